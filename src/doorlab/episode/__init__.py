"""One episode, whatever runs it: the timeline, the outer loop, the wiring and the logger
shared with the real cell, the logs, the simulated episode's life (build, run, result), the
registered controllers and the metrics of an episode.

Above the control laws and plans it runs; below the outputs of a run.
"""
