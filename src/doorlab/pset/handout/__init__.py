"""What students get and run in their folder: the 2019 notebook's API on doorlab's station,
the folder's files and notebook, the course's settings they may see, and which doorlab this
is (the instructor's, or the students' built for the handout).

:mod:`~doorlab.pset.handout.station_api` and :mod:`~doorlab.pset.handout.task_helpers` are
what the folder's files call (the student side: the student's view holds them);
:mod:`~doorlab.pset.handout.folder` writes the folder (``doorlab pset init``) from the
templates (package data, ``templates/``) and :mod:`~doorlab.pset.handout.notebook` its
notebook; :mod:`~doorlab.pset.handout.course` is ``course.yaml``, the assignment as students
may see it, which the folder's self-check grades with; :mod:`~doorlab.pset.handout.edition`
tells the two doorlabs apart (only the students' has the ``students/`` folder: the handout's
stubs and practice table).

Above :mod:`doorlab.pset.rules` (the folder shows the tests, their points and time limits); it
imports nothing else of the problem set. Of doorlab: the configuration, the cell, the plans'
base, the episode, the real arm's episode (the 2019 ``RunRealRobot``) and the runtime.
"""
