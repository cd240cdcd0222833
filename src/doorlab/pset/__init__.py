"""The 2019 problem set on doorlab: the 2019 notebook's API, the student folder, the grader.

``doorlab pset init DIR [--solutions]`` writes the folder (:func:`doorlab.pset.folder.init_folder`);
``doorlab pset grade DIR`` grades it (:func:`doorlab.pset.grader.grade`);
``doorlab pset autograder OUT.zip`` packs the grader for Gradescope
(:mod:`doorlab.pset.autograder`).
"""
