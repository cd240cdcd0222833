"""A class over a semester, for the course's staff: every submission graded in one command,
regrades, the late policy, feedback pages, statistics and gradebook exports, the Gradescope
autograder and the students' handout.

:mod:`~doorlab.pset.classroom.grade_all` is ``doorlab pset grade-all`` (locally, or on a Dask
cluster no student reaches: :mod:`~doorlab.pset.classroom.cluster`; the class's folder:
:mod:`~doorlab.pset.classroom.class_folder`; a run's bookkeeping:
:mod:`~doorlab.pset.classroom.class_run`);
:mod:`~doorlab.pset.classroom.roster` reads a class's submissions and writes its sheet;
:mod:`~doorlab.pset.classroom.regrade` plans a regrade; :mod:`~doorlab.pset.classroom.late`
applies the late policy; :mod:`~doorlab.pset.classroom.class_outputs` writes the pages and
files of a run (:mod:`~doorlab.pset.classroom.feedback`,
:mod:`~doorlab.pset.classroom.class_statistics`, :mod:`~doorlab.pset.classroom.gradebook`);
:mod:`~doorlab.pset.classroom.gradescope` packs and runs the Gradescope autograder,
:mod:`~doorlab.pset.classroom.handout_zip` writes the students' handout, and
:mod:`~doorlab.pset.classroom.wheel` the wheels both carry.

The top of :mod:`doorlab.pset`: it may import every other part of it, and nothing of the
problem set imports it. Of doorlab: the runtime (executors, output folders) and the outputs'
pages.
"""
