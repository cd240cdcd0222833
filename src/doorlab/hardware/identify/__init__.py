"""``doorlab identify``: the arm's uncertain parameters measured on the lab's arm over LCM
(:mod:`.run` the command, :mod:`.script` the motions, :mod:`.session` the status loop with its
checks, :mod:`.fit` and :mod:`.analysis` the fits and the preset they write)."""
