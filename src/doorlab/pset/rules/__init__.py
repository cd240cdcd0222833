"""The problem set's rules, shared by everyone who grades or is graded: the graded tests with
their points, margins and judges, a course's settings of them, a test's time limit, and what
the student's process must not see.

:mod:`~doorlab.pset.rules.verdicts` holds the tests (:data:`~doorlab.pset.rules.verdicts.TESTS`),
the files a student edits and the table of hidden modules
(:func:`~doorlab.pset.rules.verdicts.hidden_modules`); :mod:`~doorlab.pset.rules.assignment`
the assignment file (a course's points, margins, random seed, late policy);
:mod:`~doorlab.pset.rules.clock` a test's time limit and how the trusted side counts it.

The bottom of :mod:`doorlab.pset`: it imports nothing of the problem set's other parts, and of
doorlab only the foundations, :mod:`doorlab.config`'s checks and :mod:`doorlab.runtime.inputs`.
The handout shows these rules, isolation enforces them, grading applies them.
"""
