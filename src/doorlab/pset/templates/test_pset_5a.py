"""The problem set's grader: ``python3 test_pset_5a.py test_results.json``.

Writes Gradescope-format JSON and prints a summary; the tests and their thresholds are
described in README.md (the grader itself is doorlab.pset.grader).
"""

import sys
from pathlib import Path

from doorlab.pset.grader import main, pretty_format_json_results

__all__ = ["pretty_format_json_results"]

if __name__ == "__main__":
    sys.exit(main(sys.argv[1:], folder=Path(__file__).resolve().parent))
