"""The ``doorlab`` command: the parser (:mod:`~doorlab.cli.parser`; ``doorlab pset``'s
subcommands in :mod:`~doorlab.cli.pset_parser`, the options several commands share in
:mod:`~doorlab.cli.options`), what each command does (:mod:`~doorlab.cli.commands`) and the
console script (:mod:`~doorlab.cli.entry`); ``python -m doorlab.cli`` runs it too.

The top of the package: nothing else imports it.
"""
