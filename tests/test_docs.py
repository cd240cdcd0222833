"""The documentation site: built once per session with ``mkdocs build --strict``, then checked.

- the build passes with no warning (a broken link or anchor, a missing reference, a docstring
  mkdocstrings cannot read, a scenario field without a description all stop it);
- every CLI command and option, every scenario field, every exit status, every key of
  metrics.json and channel of log.npz, every module appear in the built reference pages
  (walked here from the code, independently of docs/tools/reference.py's walk);
- a real run folder holds only files the reference lists;
- the built HTML loads nothing from another host, and the theme links to none;
- the home page, a guide and the API reference, served on loopback, render in headless
  Chromium with their navigation and load nothing from elsewhere (and screenshots of them are
  taken: set DOORLAB_DOCS_SCREENSHOTS=DIR to keep them).
"""

from __future__ import annotations

import argparse
import dataclasses
import html
import importlib.util
import json
import os
import re
import subprocess
import sys
import time
from html.parser import HTMLParser
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BUILD_TIMEOUT_S = 600


def _reference_module():
    """docs/tools/reference.py (the generator) as a module."""
    path = ROOT / "docs" / "tools" / "reference.py"
    spec = importlib.util.spec_from_file_location("doorlab_docs_reference", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The site built with ``mkdocs build --strict`` into a temporary folder."""
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}  # Material's banner, not a warning
    start = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env=env,
        timeout=BUILD_TIMEOUT_S,
        check=False,
    )
    elapsed = time.perf_counter() - start
    assert done.returncode == 0, f"mkdocs build --strict failed:\n{done.stderr[-6000:]}"
    warnings = [line for line in done.stderr.splitlines() if "WARNING" in line]
    assert warnings == [], warnings
    print(f"mkdocs build --strict: {elapsed:.1f} s")
    return out


@pytest.fixture(scope="module")
def served(site: Path):
    """The built site served over HTTP on loopback (as ``mkdocs serve`` would): its URL."""
    import functools
    import http.server
    import threading

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args) -> None:
            pass

    handler = functools.partial(Quiet, directory=str(site))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_address[1]}/"
    server.shutdown()
    server.server_close()


def _text(page: Path) -> str:
    """A built page's HTML with entities decoded."""
    return html.unescape(page.read_text(encoding="utf-8"))


def _section(page_html: str, anchor: str) -> str:
    """The HTML of the section whose heading has id ``anchor``, up to the next heading of
    the same or a higher level."""
    match = re.search(rf'<h([1-6])[^>]*\bid="{re.escape(anchor)}"', page_html)
    assert match, f"no heading with id {anchor!r}"
    level = int(match.group(1))
    end = re.compile(rf"<h[1-{level}][\s>]").search(page_html, match.end())
    return page_html[match.start() : end.start() if end else len(page_html)]


@pytest.mark.slow
def test_every_page_of_the_nav_is_built(site: Path):
    import yaml

    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text())

    def pages(nav):
        for item in nav:
            value = next(iter(item.values())) if isinstance(item, dict) else item
            if isinstance(value, list):
                yield from pages(value)
            else:
                yield value

    built = [site / Path(p).with_suffix(".html") for p in pages(config["nav"])]
    assert len(built) >= 20
    assert [p for p in built if not p.is_file()] == []


def _commands(parser: argparse.ArgumentParser, words: tuple[str, ...] = ("doorlab",)):
    yield words, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _commands(sub, (*words, name))


@pytest.mark.slow
def test_every_cli_command_and_option_is_in_the_reference(site: Path):
    """Each command has its section, and each of its options is named in it, in code."""
    from doorlab.cli.parser import build_parser

    page = _text(site / "reference" / "cli.html")
    commands = list(_commands(build_parser()))
    assert len(commands) >= 8  # doorlab, run, report, sweep, pset (init, grade, autograder)...
    checked = 0
    for words, parser in commands:
        section = _section(page, "-".join(words))
        assert f"<code>{' '.join(words)}</code>" in section
        for action in parser._actions:
            if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)):
                continue
            names = action.option_strings or [action.metavar or action.dest]
            for name in names:
                assert f"<code>{name}</code>" in section, f"{' '.join(words)}: {name}"
                checked += 1
            if action.help:  # its description too (the first words, before any markup)
                words_of_help = " ".join(action.help.split()[:3])
                assert html.escape(words_of_help, quote=False) in section or (
                    words_of_help in section
                ), f"{' '.join(words)} {names}: {action.help!r}"
    assert checked >= 40


def _scenario_fields(cls, prefix: str = ""):
    for f in dataclasses.fields(cls):
        dotted = prefix + f.name
        if dataclasses.is_dataclass(f.type):
            yield from _scenario_fields(f.type, dotted + ".")
        else:
            yield dotted, f


def test_every_scenario_field_is_in_the_reference(site: Path):
    """Each field has a row: its dotted name, its type and a description."""
    from doorlab.config import Scenario

    page = _text(site / "reference" / "scenario.html")
    fields = list(_scenario_fields(Scenario))
    assert len(fields) >= 60
    for dotted, _ in fields:
        row = re.search(rf"<tr>\s*<td><code>{re.escape(dotted)}</code></td>(.*?)</tr>", page, re.S)
        assert row, f"no row for scenario field {dotted}"
        cells = re.findall(r"<td>(.*?)</td>", row.group(1), re.S)
        assert len(cells) == 4, (dotted, cells)
        assert cells[0].strip(), f"{dotted}: no type"
        assert re.sub(r"<[^>]+>", "", cells[3]).strip(), f"{dotted}: no description"
    assert "station.inner_loop.kq" in page and "N m/rad" in page  # a unit from a comment


def test_units_come_from_the_fields_comments():
    """The generator reads the unit of a field from its comment ([unit] first)."""
    reference = _reference_module()
    rows = {r.name: r for r in reference.scenario_fields()}
    assert rows["station.time_step"].unit == "s"
    assert rows["station.inner_loop.kq"].unit == "N m/rad"
    assert rows["station.inner_loop.dq"].unit == "N m s/rad"
    assert rows["station.cupboard_yaw_error"].unit == "rad"  # from a comment block above it
    assert rows["adaptive.force_gain"].unit == "m/(N s)"
    assert rows["station.gripper.grasp_width"].default == "0.005"
    assert "`ik`, `velocity`" in rows["controller"].text  # "one of CONTROLLERS" spelled out
    # every float-valued field has a unit ([-] for a ratio): the team writes units in comments
    floats = [r for r in rows.values() if not r.is_section and "float" in r.type]
    assert [r.name for r in floats if not r.unit] == []


def test_the_reference_follows_the_code(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """What another branch adds appears by itself, and what it leaves undocumented stops the
    build with a message naming it: a new option, a field without a comment, a new module."""
    reference = _reference_module()
    import doorlab.cli.parser

    build = doorlab.cli.parser.build_parser

    def with_new_option():
        parser = build()
        run = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[
            "run"
        ]
        run.add_argument("--brand-new", metavar="N", help="an option added on another branch")
        return parser

    monkeypatch.setattr(doorlab.cli.parser, "build_parser", with_new_option)
    cli = reference.cli_markdown()
    run_section = cli[cli.index("{#doorlab-run}") : cli.index("{#doorlab-report}")]
    assert "| `--brand-new` | `N` |  | an option added on another branch |" in run_section

    module = tmp_path / "new_config.py"
    module.write_text(
        "from dataclasses import dataclass, field\n\n\n"
        "@dataclass\nclass Inner:\n"
        "    gain: float = 2.0  # [1/s] a documented gain\n"
        "    forgotten: float = 1.0\n\n\n"
        "@dataclass\nclass Outer:\n"
        "    # [m] a length, documented above the field\n"
        "    length: float = 0.5\n"
        "    inner: Inner = field(default_factory=Inner)\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    import new_config

    rows = {r.name: r for r in reference.scenario_fields(new_config.Outer)}
    assert (rows["length"].unit, rows["length"].text) == (
        "m",
        "a length, documented above the field",
    )
    assert (rows["inner.gain"].unit, rows["inner.gain"].default) == ("1/s", "2.0")
    with pytest.raises(ValueError, match="inner.forgotten"):
        reference.scenario_markdown(new_config.Outer)

    import doorlab_reference.api  # the hook put its package on sys.path

    modules = reference.package_modules()
    monkeypatch.setattr(
        doorlab_reference.api, "package_modules", lambda: [*modules, "doorlab.brand_new"]
    )
    with pytest.raises(ValueError, match="doorlab.brand_new"):
        reference.api_coverage()
    with pytest.raises(ValueError, match="unknown marker"):
        reference.expand("<!-- doorlab:nonsense -->\n")


def test_exit_codes_outputs_and_logs_are_in_the_reference(site: Path):
    from doorlab.control.adaptive import LOG_CHANNELS
    from doorlab.episode.metrics import DoorMetrics
    from doorlab.episode.result import EpisodeResult
    from doorlab.outputs.runs import EXIT_CODES

    codes = _text(site / "reference" / "exit-codes.html")
    for status, code in EXIT_CODES.items():
        assert re.search(rf"<td>{code}</td>\s*<td><code>{status}</code></td>", codes), status
    assert "130 (SIGINT)" in codes
    outputs = _text(site / "reference" / "outputs.html")
    metrics = _section(outputs, "metricsjson")
    for f in dataclasses.fields(DoorMetrics):
        assert f"<code>{f.name}</code>" in metrics, f.name
    logs = _section(outputs, "lognpz")
    for f in dataclasses.fields(EpisodeResult):
        assert f"<code>{f.name}</code>" in logs, f.name
    from doorlab.control.diffik import LOG_CHANNELS as DIFFIK_CHANNELS

    for name in (*LOG_CHANNELS, *DIFFIK_CHANNELS):
        assert f"<code>plan_log.{name}</code>" in logs, name


@pytest.mark.slow
def test_a_run_folder_holds_only_documented_files(site: Path, tmp_path: Path):
    """A real (short) run's folder: every file it holds is listed in the reference."""
    from report_fixtures import short_scenario

    from doorlab.outputs.runs import run_to_folder

    outcome = run_to_folder(short_scenario("velocity", "open"), tmp_path / "run")
    assert outcome.status == "ok"
    files = sorted(p.name for p in (tmp_path / "run").iterdir())
    assert len(files) >= 10
    page = _section(_text(site / "reference" / "outputs.html"), "a-run-folder")
    assert [f for f in files if f"<code>{f}</code>" not in page] == []


def test_every_module_is_in_the_api_reference(site: Path):
    """Each module of src/doorlab has its heading (mkdocstrings' id is its dotted path), in
    the sub-packages too."""
    import pkgutil

    import doorlab

    modules = [
        m.name
        for m in pkgutil.walk_packages(
            [str(Path(doorlab.__file__).parent)], prefix="doorlab.", onerror=lambda _: None
        )
        if not m.name.rsplit(".", 1)[1].startswith("_")  # doorlab.cli.__main__: no API
    ]
    assert len(modules) >= 60
    assert "doorlab.cell.station" in modules and "doorlab.episode.result" in modules
    pages = "".join(p.read_text() for p in (site / "reference" / "api").glob("*.html"))
    assert [m for m in modules if f'id="{m}"' not in pages] == []
    public = _text(site / "reference" / "api" / "index.html")
    for name in doorlab.__all__:
        assert f"<code>{name}</code>" in public, name


class _References(HTMLParser):
    """URLs an HTML page loads (src, srcset, stylesheets, icons...) and the links it has."""

    LOADING = {"src", "srcset", "data", "poster", "background"}

    def __init__(self) -> None:
        super().__init__()
        self.loads: list[str] = []
        self.links: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        for name, value in attrs:
            if value is None:
                continue
            if name in self.LOADING:
                self.loads += [v.strip().split()[0] for v in value.split(",") if v.strip()]
            elif name == "href":
                (self.links if tag == "a" else self.loads).append(value)
            elif name == "style":
                self.loads += re.findall(r"url\(\s*['\"]?([^'\")]+)", value)


def _external(url: str) -> bool:
    return bool(re.match(r"^(?:[a-z][a-z0-9+.-]*:)?//", url, re.I))


def test_the_site_loads_nothing_from_another_host(site: Path):
    """No page, stylesheet or script source names another host (fonts, CDNs, analytics), and
    every link to another host is one an author wrote in docs/ (the theme adds none)."""
    authored = "\n".join(p.read_text() for p in (ROOT / "docs").rglob("*.md"))
    pages = list(site.rglob("*.html"))
    assert len(pages) >= 20
    bad_loads, foreign_links = [], []
    for page in pages:
        parser = _References()
        parser.feed(page.read_text(encoding="utf-8"))
        bad_loads += [(page.name, u) for u in parser.loads if _external(u)]
        foreign_links += [
            (page.name, u) for u in parser.links if _external(u) and u not in authored
        ]
        text = page.read_text(encoding="utf-8")
        bad_loads += [(page.name, u) for u in re.findall(r"@import\s+url\(([^)]*//[^)]*)\)", text)]
    for sheet in site.rglob("*.css"):
        for url in re.findall(r"url\(\s*['\"]?([^'\")]+)", sheet.read_text(encoding="utf-8")):
            if _external(url):
                bad_loads.append((sheet.name, url))
    assert bad_loads == []
    assert foreign_links == []


NAV_CHECK = """
<script>
window.addEventListener("load", () => {
  const visible = (e) => {
    const r = e.getBoundingClientRect();
    return r.width > 0 && r.height > 0;
  };
  const nav = document.querySelector("nav.md-nav--primary");
  const links = nav ? Array.from(nav.querySelectorAll(".md-nav__link")).filter(visible) : [];
  const header = document.querySelector("header.md-header");
  const article = document.querySelector("article");
  const images = Array.from(document.querySelectorAll("article img"));
  const result = {
    nav_visible: !!nav && visible(nav),
    nav_links: links.map(a => a.textContent.trim()),
    nav_anchors: links.filter(a => a.tagName === "A").length,
    header_color: header ? getComputedStyle(header).backgroundColor : null,
    title: (document.querySelector("article h1") || {}).textContent || null,
    content_height: article ? article.getBoundingClientRect().height : 0,
    images: images.length,
    broken_images: images.filter(i => !(i.complete && i.naturalWidth > 0)).map(i => i.alt),
    resources: performance.getEntriesByType("resource").map(e => e.name),
  };
  const out = document.createElement("pre");
  out.id = "nav-check";
  out.textContent = JSON.stringify(result);
  document.body.appendChild(out);
});
</script>
"""

SCREEN = (1400, 1000)
"""Window size [px]: wide enough for Material's left navigation (shown from 1220 px)."""


def _chromium(binary: str, profile: Path, *args: str) -> subprocess.CompletedProcess:
    from test_report_browser import BROWSER_TIMEOUT_S

    from doorlab.runtime.pdf import HEADLESS_FLAGS

    flags = [  # no host resolves but the loopback address the site is served on
        "--host-resolver-rules=MAP * ~NOTFOUND , EXCLUDE 127.0.0.1"
        if f.startswith("--host-resolver-rules=")
        else f
        for f in HEADLESS_FLAGS
    ]
    command = [
        binary,
        *flags,
        f"--user-data-dir={profile}",
        f"--window-size={SCREEN[0]},{SCREEN[1]}",
        "--hide-scrollbars",
        "--virtual-time-budget=5000",
        *args,
    ]
    return subprocess.run(
        command, capture_output=True, text=True, timeout=BROWSER_TIMEOUT_S, check=False
    )


@pytest.mark.slow
@pytest.mark.parametrize(
    "page, title",
    [
        ("index.html", "doorlab"),
        ("guides/sweeps.html", "Sweeps: any scenario field over a grid or random samples"),
        ("reference/api/control.html", "Control laws and plans"),
    ],
)
def test_pages_render_with_their_navigation(
    site: Path, served: str, tmp_path: Path, page: str, title: str
):
    """In headless Chromium the page has its styled header, the site's navigation on the left
    with every top-level section, its title, content and images, and loaded nothing but the
    site's own files; a screenshot is taken."""
    from test_report_browser import chromium

    binary = chromium()
    if binary is None:
        pytest.skip("chromium not installed: apt-get install chromium")
    source = site / page
    copy = source.with_name(f"{source.stem}_navcheck.html")  # beside it: relative assets load
    copy.write_text(
        source.read_text(encoding="utf-8").replace("</body>", NAV_CHECK + "</body>"),
        encoding="utf-8",
    )
    url = served + copy.relative_to(site).as_posix()
    done = _chromium(binary, tmp_path / "profile", "--dump-dom", url)
    copy.unlink()
    match = re.search(r'<pre id="nav-check">(.*?)</pre>', done.stdout, flags=re.S)
    assert match, f"no check in the DOM (exit {done.returncode}): {done.stderr[-2000:]}"
    result = json.loads(html.unescape(match.group(1)))
    assert result["nav_visible"], result
    for section in ("Home", "Getting started", "Guides", "Reference", "Explanation"):
        assert section in result["nav_links"], (section, result["nav_links"])
    assert result["nav_anchors"] >= 10, result  # the sections' pages are links
    assert result["header_color"] not in (None, "rgba(0, 0, 0, 0)", "rgb(255, 255, 255)"), (
        "the theme's stylesheet did not load",
        result,
    )
    assert (result["title"] or "").strip().rstrip("¶").strip() == title
    assert result["content_height"] > 300
    assert result["broken_images"] == []
    assert len(result["resources"]) >= 3  # the theme's stylesheets and scripts
    assert [u for u in result["resources"] if not u.startswith(served)] == []

    keep = os.environ.get("DOORLAB_DOCS_SCREENSHOTS")
    shots = Path(keep) if keep else tmp_path
    shots.mkdir(parents=True, exist_ok=True)
    png = shots / (page.replace("/", "_").replace(".html", ".png"))
    done = _chromium(binary, tmp_path / "profile2", f"--screenshot={png}", served + page)
    assert png.is_file(), done.stderr[-2000:]
    import matplotlib.image

    pixels = matplotlib.image.imread(png)[..., :3]
    assert pixels.shape[:2] == (SCREEN[1], SCREEN[0])
    header = pixels[5:40, :, :].reshape(-1, 3)
    assert (header.std(axis=1) > 0.02).mean() > 0.5 or header.mean() < 0.9  # colored, not blank
    sidebar = pixels[80:, 20:260, :]
    assert (sidebar.mean(axis=2) < 0.5).mean() > 0.002  # the navigation's text is drawn


def test_every_measured_region_is_what_its_run_wrote():
    """What a page quotes from a run (``<!-- measured: T/NAME -->`` regions: figures, tables,
    summaries, times) is exactly what ``docs/tools/make_figures.py`` wrote from the run's
    outputs in docs/figures: no region typed or edited by hand, none stale against them."""
    sys.path.insert(0, str(ROOT / "docs" / "tools"))
    try:
        from doorlab_reference import measured
    finally:
        sys.path.remove(str(ROOT / "docs" / "tools"))
    regions = [
        (page, m.group("name"))
        for page in measured.pages()
        for m in measured.REGION.finditer(page.read_text())
    ]
    assert len(regions) >= 15, regions  # the run's, the report's, the sweeps' figures and texts
    assert measured.stale() == []


def test_a_region_typed_by_hand_is_found(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """The check is not blind: a page whose region was edited by hand is stale."""
    sys.path.insert(0, str(ROOT / "docs" / "tools"))
    try:
        from doorlab_reference import measured
    finally:
        sys.path.remove(str(ROOT / "docs" / "tools"))
    page = ROOT / "docs" / "getting-started.md"
    text = page.read_text()
    edited = re.sub(r"(door opened at the arc's end\s+)[\d.]+", r"\g<1>45.0", text, count=1)
    assert edited != text
    copy = tmp_path / "docs" / "getting-started.md"
    copy.parent.mkdir()
    copy.write_text(edited)
    monkeypatch.setattr(measured, "ROOT", tmp_path)
    monkeypatch.setattr(measured, "pages", lambda: [copy])
    assert measured.stale() == ["docs/getting-started.md"]
