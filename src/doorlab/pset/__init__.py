"""The 2019 problem set on doorlab: what students get, their code contained, the grader's
judgement and a class over a semester, one sub-package each, above the rules they share.

From the bottom up (each imports only from itself and the ones before it in this list:
``tests/test_imports.py``):

- :mod:`doorlab.pset.rules`: the graded tests and how each is judged, a course's settings of
  them (the assignment file), a test's time; what the student's process must not see;
- :mod:`doorlab.pset.handout`: what students get and run in their folder: the 2019 API on
  doorlab's station, the folder's files and notebook, the course's settings they may see,
  which doorlab this is (the instructor's or the students');
- :mod:`doorlab.pset.isolation`: the student's code contained: the intake of a submission,
  the student's process and its channel, the sandbox, the minimal root (bubblewrap), the
  cgroups, the system-call filter, the honesty guard;
- :mod:`doorlab.pset.grading`: the trusted side's judgement of one submission: the
  supervisor and its jobs, the unit tests and episodes, the answer key, the results;
- :mod:`doorlab.pset.classroom`: a class over a semester: every submission graded at once, the
  roster and the sheet, regrades, the late policy, feedback pages, statistics, gradebook
  exports, the Gradescope autograder, the handout's zip and the wheels.

``doorlab pset init DIR [--solutions]`` writes the folder
(:func:`doorlab.pset.handout.folder.init_folder`); ``doorlab pset assignment FILE`` the
course's grading settings (:mod:`doorlab.pset.rules.assignment`); ``doorlab pset handout
OUT.zip`` what students get (:mod:`doorlab.pset.classroom.handout_zip`); ``doorlab pset grade
SUBMISSION`` grades a submission through the one intake
(:func:`doorlab.pset.grading.grader.grade_submission`, :mod:`doorlab.pset.isolation.intake`);
``doorlab pset grade-all`` a class (:mod:`doorlab.pset.classroom.grade_all`); ``doorlab pset
autograder OUT.zip`` packs the grader for Gradescope (:mod:`doorlab.pset.classroom.gradescope`).

This package's and its sub-packages' ``__init__`` import nothing: the student's view holds a
few of their modules (:data:`doorlab.pset.isolation.bwrap_root.STUDENT_MODULES`), and
importing one loads only what it imports itself.
"""
