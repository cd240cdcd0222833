"""One episode, whatever runs it: the timeline (:mod:`~doorlab.episode.schedule`), the outer
loop (:mod:`~doorlab.episode.plan_runner`), the wiring and the logger shared with the real
cell (:mod:`~doorlab.episode.wiring`), the logs (:mod:`~doorlab.episode.result`), the
simulated episode's life, build, run, result (:mod:`~doorlab.episode.simulation`), the
registered controllers (:mod:`~doorlab.episode.controllers`) and the metrics of an episode
(:mod:`~doorlab.episode.metrics`).
"""
