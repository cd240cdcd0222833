"""The trusted side's judgement of one submission, for the instructor and Gradescope: the
grader, its supervisor and the jobs it forks, the unit tests and the episodes simulated here,
the answer key and the results.

:mod:`~doorlab.pset.grading.grader` is ``doorlab pset grade`` (a grading, the supervisor that
serves many); :mod:`~doorlab.pset.grading.supervisor` and :mod:`~doorlab.pset.grading.jobs`
the processes that run a grading's jobs; :mod:`~doorlab.pset.grading.checks` the unit tests
and :mod:`~doorlab.pset.grading.episodes` the episodes, both asking the student's process for
numbers; :mod:`~doorlab.pset.grading.answer_key` the expected answers and the reference
episodes (the students' doorlab leaves it out); :mod:`~doorlab.pset.grading.scoring` the
scoring (each test judged at the assignment's points: the Gradescope results), and
:mod:`~doorlab.pset.grading.rescore` new results from what a grading stored.

Above :mod:`doorlab.pset.rules`, :mod:`doorlab.pset.handout` and
:mod:`doorlab.pset.isolation`; below the classroom. Of doorlab: the configuration, the cell,
the episodes and the reference solutions (the control laws, the pointwise IK, the registered
controllers), which no student process imports.
"""
