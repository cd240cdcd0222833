"""The parsers of ``doorlab pset``'s subcommands: ``init`` (the problem-set folder),
``grade`` (one submission), ``grade-all`` (a whole class), ``feedback`` (each student's page to
hand out), ``autograder`` (the Gradescope zip), ``handout`` (the students' zip),
``assignment`` (the course's settings file) and ``cluster-keys`` (a course's Dask cluster's
keys). :func:`doorlab.cli.parser.build_parser` adds them with :func:`add_pset_parser`; what
each does is :func:`doorlab.cli.commands.pset`'s.
"""

from __future__ import annotations

from pathlib import Path

from doorlab.cli.options import add_scheduler_options
from doorlab.runtime.argtypes import OneLineParser, bounded_int


def add_pset_parser(sub) -> None:
    """``doorlab pset {init,grade,grade-all,feedback,autograder,handout,assignment,cluster-keys}``:
    the problem-set folder, its grader (one submission, or a whole class), each student's
    feedback to hand out, the grader as a Gradescope autograder zip, the students' handout, the
    assignment file and the keys of a course's Dask cluster."""
    pset = sub.add_parser("pset", help="write the problem-set folder for students, or grade one")
    actions = pset.add_subparsers(
        dest="pset_command",
        metavar="{init,grade,grade-all,feedback,autograder,handout,assignment,cluster-keys}",
        parser_class=OneLineParser,
        required=True,
    )
    init = actions.add_parser("init", help="write the problem-set folder DIR")
    init.add_argument("dir", type=Path, metavar="DIR", help="the folder to write")
    init.add_argument(
        "--solutions", action="store_true", help="write the reference solutions, not the stubs"
    )
    init.add_argument("--force", action="store_true", help="replace an existing DIR")
    grade = actions.add_parser(
        "grade", help="grade a submission (a problem-set folder, its three files, or a zip)"
    )
    grade.add_argument(
        "dir",
        type=Path,
        metavar="SUBMISSION",
        help="a folder (the problem set's, or holding its student files at any depth) or a .zip",
    )
    grade.add_argument(
        "--out",
        type=Path,
        default=None,
        help="results JSON (Gradescope format; default SUBMISSION/test_results.json, or "
        "NAME_results.json beside a NAME.zip)",
    )
    grade.add_argument(
        "--jobs", type=bounded_int(1), default=2, help="tests run at a time (default 2)"
    )
    grade.add_argument(
        "--reference",
        type=Path,
        default=None,
        metavar="RESULTS_JSON",
        help="reuse the reference episodes of an earlier grading's results (saves 3 episodes)",
    )
    _assignment_option(grade)
    grade.add_argument(
        "--seed",
        type=bounded_int(0, 2**63 - 1),
        default=None,
        metavar="N",
        help="the grading seed of a recorded grading (its results' extra_data.seed.grading): "
        "replays its random inputs",
    )
    grade.add_argument(
        "--insecure",
        action="store_true",
        help="grade even where the student's code cannot be isolated (no bubblewrap, no user "
        "namespaces); the results and the summary say so",
    )
    add_grade_all_parser(actions)
    hand_out = actions.add_parser(
        "feedback",
        help="write each student's feedback page (or PDF) of a graded class into OUT, named by "
        "student id and name, with an index.csv: for a course without Gradescope",
    )
    hand_out.add_argument(
        "class_dir", type=Path, metavar="DIR", help="the class's folder (grade-all --out DIR)"
    )
    hand_out.add_argument("out", type=Path, metavar="OUT", help="the new folder of the files")
    hand_out.add_argument(
        "--pdf", action="store_true", help="PDFs printed by headless Chromium, not HTML pages"
    )
    hand_out.add_argument(
        "--force", action="store_true", help="replace an existing OUT written by doorlab"
    )
    add_cluster_keys_parser(actions)
    auto = actions.add_parser(
        "autograder", help="write a Gradescope autograder zip that grades with this doorlab"
    )
    auto.add_argument("out", type=Path, metavar="OUT.zip", help="the zip to write")
    auto.add_argument(
        "--jobs",
        type=bounded_int(1),
        default=1,
        help="tests run at a time on Gradescope (default 1; 2 with 2 CPUs and 1.5 GB)",
    )
    _assignment_option(auto)
    auto.add_argument(
        "--force", action="store_true", help="replace an existing OUT.zip written by doorlab"
    )
    hand = actions.add_parser(
        "handout", help="write the students' zip: the problem-set folder and doorlab's wheel"
    )
    hand.add_argument("out", type=Path, metavar="OUT.zip", help="the zip to write")
    _assignment_option(hand, "the README's points and margins")
    hand.add_argument(
        "--force", action="store_true", help="replace an existing OUT.zip written by doorlab"
    )
    hand.add_argument(
        "--reference",
        type=Path,
        default=None,
        metavar="EARLIER.json",
        help="the practice table's reference episodes from an earlier results file (default: "
        "simulated now)",
    )
    assignment = actions.add_parser(
        "assignment", help="write the default assignment file (points, margins, random seed, ...)"
    )
    assignment.add_argument("out", type=Path, metavar="FILE", help="the YAML file to write")


def add_cluster_keys_parser(actions) -> None:
    """``doorlab pset cluster-keys DIR``: a course's Dask cluster's TLS keys."""
    keys = actions.add_parser(
        "cluster-keys",
        help="write a Dask cluster's TLS keys into DIR: its certificate authority (ca.pem) and "
        "a certificate and key for the scheduler, the workers and grade-all's client",
    )
    keys.add_argument("out", type=Path, metavar="DIR", help="the folder to write (mode 0700)")
    keys.add_argument(
        "--host",
        action="append",
        default=[],
        metavar="HOST",
        help="a name or address the scheduler and workers are reached at, put in their "
        "certificates; repeat for more (default: localhost and 127.0.0.1)",
    )
    keys.add_argument("--force", action="store_true", help="replace a DIR that doorlab wrote")


def add_grade_all_parser(actions) -> None:
    """``doorlab pset grade-all SUBMISSIONS --out DIR``: a whole class into a grade sheet."""
    grade_all = actions.add_parser(
        "grade-all",
        help="grade every submission of a class (Gradescope's export, or a folder of folders "
        "and zips) into DIR/grades.csv and DIR/<submission>/results.json",
    )
    grade_all.add_argument(
        "submissions",
        type=Path,
        metavar="SUBMISSIONS",
        help="Gradescope's 'Export Submissions' folder (submission_metadata.yml names the "
        "students), or any folder of submission folders and .zip files",
    )
    grade_all.add_argument(
        "--out",
        type=Path,
        required=True,
        metavar="DIR",
        help="the class's folder: grades.csv, one results.json per submission, feedback/ "
        "(a page per submission), class.html, summary.json, summary.txt, class.json",
    )
    _assignment_option(grade_all)
    grade_all.add_argument(
        "--jobs",
        type=bounded_int(1),
        default=None,
        help="submissions graded at a time, one local worker process each (default: the "
        "number of cores)",
    )
    add_scheduler_options(grade_all)
    grade_all.add_argument(
        "--cluster-keys",
        type=Path,
        default=None,
        metavar="DIR",
        help="with a tls:// --scheduler: the folder doorlab pset cluster-keys wrote (its ca.pem, "
        "client.pem and client.key; default: Dask's configuration's certificates)",
    )
    grade_all.add_argument(
        "--insecure-cluster",
        action="store_true",
        help="grade on a --scheduler without TLS or that lets clients in without a key (a "
        "warning says that whoever reaches it can change every grade)",
    )
    grade_all.add_argument(
        "--reference",
        type=Path,
        default=None,
        metavar="RESULTS_JSON",
        help="grade against the reference episodes of an earlier grading's results (default: "
        "simulate them once for the class)",
    )
    grade_all.add_argument(
        "--resume",
        action="store_true",
        help="regrade the class in DIR: grade what changed (new files, failed gradings, new "
        "submissions), re-score from the stored figures what only points, visibility or "
        "margins need, keep the rest; DIR/changes.csv says what changed",
    )
    grade_all.add_argument(
        "--only",
        action="append",
        default=[],
        metavar="ID",
        help="regrade (simulate again) only this submission of the class in DIR, keeping the "
        "others; repeat for more",
    )
    grade_all.add_argument(
        "--export",
        action="append",
        default=[],
        choices=("canvas", "gradescope"),
        help="also write DIR/canvas.csv (Canvas's gradebook import) or DIR/gradescope.csv "
        "(one row per student by Gradescope's name, e-mail and SID, for another gradebook's CSV "
        "import); repeat for both; every later run rewrites the exports DIR holds",
    )
    grade_all.add_argument(
        "--roster",
        type=Path,
        default=None,
        metavar="FILE",
        help="the course's Canvas gradebook export (Grades, Export): --export canvas fills its "
        "students (matched by e-mail, then SIS User ID) with Canvas's ID, names and sections; "
        "kept in DIR for later runs",
    )
    grade_all.add_argument(
        "--pdf",
        action="store_true",
        help="print each feedback page to DIR/feedback/<submission>.pdf (headless Chromium)",
    )
    grade_all.add_argument(
        "--published",
        action="store_true",
        help="the course has published its grades: feedback pages show the after_published "
        "tests too",
    )
    grade_all.add_argument(
        "--force", action="store_true", help="start over in a DIR that doorlab wrote"
    )
    grade_all.add_argument(
        "--insecure",
        action="store_true",
        help="grade even where the student's code cannot be isolated (every result says so)",
    )


def _assignment_option(
    parser, what: str = "points, margins, visibility, random seed, helpers"
) -> None:
    parser.add_argument(
        "--assignment",
        type=Path,
        default=None,
        metavar="FILE",
        help=f"the course's assignment file ({what}; doorlab pset assignment FILE writes one)",
    )
