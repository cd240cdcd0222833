"""``python -m doorlab.cli``: the ``doorlab`` command (:func:`doorlab.cli.entry.main`)."""

import sys

from doorlab.cli.entry import main

sys.exit(main())
