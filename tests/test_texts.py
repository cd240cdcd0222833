"""What a newcomer reads names the problem set for what it is (issue 20): "seed" in the README,
the package and the examples is only ever the random seed of sweeps and sampling."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TEXTS = (".py", ".j2", ".md", ".yaml", ".ipynb", ".css", ".html")
RANDOM = re.compile(
    r"random|rng|sampl|\bseed\b\s*(:|=|<)|\.seed\b|\"seed\"|SeedSequence|seed must be|"
    r"from the seed$|from ``seed``|SPEC_KEYS|--seed\b|grading seed",
    re.I,
)


def _files() -> list[Path]:
    files = [ROOT / "README.md"]
    for folder in ("src", "examples", "docs"):
        files += [
            p
            for p in (ROOT / folder).rglob("*")
            if p.suffix in TEXTS and p.is_file() and ".egg-info" not in str(p)
        ]
    return files


def test_seed_means_only_the_random_seed():
    files = _files()
    assert len(files) > 100  # the walk found the package
    found = [
        f"{path.relative_to(ROOT)}:{n}: {line.strip()}"
        for path in files
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        if re.search(r"\bseed\b", line, re.I) and not RANDOM.search(line)
    ]
    assert not found, "\n".join(found[:20])


def test_the_check_catches_the_old_wording():
    for line in ("Every run follows the seed's timeline", "the seed notebook's API"):
        assert re.search(r"\bseed\b", line, re.I) and not RANDOM.search(line)
