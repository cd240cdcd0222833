"""The 2019 problem set on doorlab: the 2019 notebook's API, the student folder, the grader.

``doorlab pset init DIR [--solutions]`` writes the folder (:func:`doorlab.pset.folder.init_folder`);
``doorlab pset assignment FILE`` the course's grading settings (:mod:`doorlab.pset.assignment`);
``doorlab pset handout OUT.zip`` what students get (:mod:`doorlab.pset.handout`);
``doorlab pset grade SUBMISSION`` grades a submission through the one intake
(:func:`doorlab.pset.grader.grade_submission`, :mod:`doorlab.pset.intake`);
``doorlab pset autograder OUT.zip`` packs the grader for Gradescope
(:mod:`doorlab.pset.autograder`).
"""
