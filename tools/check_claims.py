r"""Check every figure the documents quote as a result against its committed data file.

    python tools/check_claims.py                 # the documents against the committed data
    python tools/check_claims.py --recompute 6   # also re-run 6 of the kept runs on today's code

Two kinds of claims are checked:

* **Generated sections.** The README's claims (between the markers of
  ``benchmarks/fair_results.py claims``) and docs/results.md's fair comparison are made by
  ``benchmarks/fair_results.py`` from ``docs/results/fair/``; they are rebuilt here from
  the kept runs (``runs.parquet``, the statistics recomputed with the same seeded
  bootstrap) and must equal the committed text, and ``claims.json`` must equal the claims
  rebuilt from the runs. Every number in the sections is counted as a checked figure.
* **Rendered sections.** The sections of :data:`SECTIONS` (docs/results.md's verdicts
  and tables from ``docs/results/runs.parquet`` through benchmarks/results.py's
  ``statistics_section``, docs/controllers.md's
  full-state results from ``docs/results/full_state_controllers.csv`` and its baselines'
  verdicts from ``docs/results/runs.parquet`` with ``controllers_confirm.parquet``
  (benchmarks/controller_evidence.py), docs/safety.md's filter verdicts from
  ``benchmarks/results/safety_filter_*_hocbf*.csv`` (benchmarks/safety_evidence.py),
  docs/identify.md's
  double cart-pole seeds from ``benchmarks/results/identify_seeds_articulated.json``,
  docs/results.md's tuning curves from ``docs/results/fair/tuning_curves.json``) are
  rebuilt by their benchmark's own renderer from the committed data and must equal the
  committed text; their numbers count as checked figures.
* **Marked figures.** Anywhere in README.md and docs/*.md, a number followed by
  ``<!-- data: FILE KEY -->`` (FILE relative to the repository, a JSON file; KEY a path
  into it with ``/`` between the steps, list entries by index; an optional ``xSCALE``
  after it multiplies the value: ``x100`` for a fraction printed in %) must equal the
  file's value to the digits printed (a figure printed as 0.0123 holds for any value that
  rounds to it).
  A ``.txt`` FILE is a benchmark's committed raw output: KEY is then a regular expression
  (no spaces: write ``\s`` or ``\s+``) that must match the file exactly once; its first
  group (the whole match without one) is the number the figure must equal at its printed
  digits, e.g. ``<!-- data: benchmarks/results/x.txt median\s+([\d.]+)\s+ms -->``.

**Unchecked figures.** Every other number of README.md and docs/*.md that a reader may
take for a result is listed, ``FILE:LINE: figures``, and counted: a number in prose or in a
table, outside fenced blocks (commands and their output, source excerpts), code spans,
HTML comments, link targets and headings. The count may not exceed
:data:`UNCHECKED_AT_MOST`: a new unmarked figure fails the check until it is marked (or
the ceiling is raised on purpose), and the ceiling goes down as figures are tied to data.
So changing any one number of a results table or a verdict sentence either fails a check
above or shows on that list.

``--recompute N``: re-runs N of the kept test runs (``runs.parquet``) from the committed
tuned scenarios (``tuned/SCENARIO-KIND.toml``) with today's code and fails when a metric
differs by more than 1e-9 relative: data that today's code no longer reproduces.

Exit 0 when every figure agrees; 1 otherwise, each difference named.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT))
FAIR = ROOT / "docs" / "results" / "fair"
NUMBER = re.compile(r"[-−]?\d+(?:,\d{3})*(?:\.\d+)?(?:e[-+]?\d+)?", re.I)
#: a marked figure; a hyphen right after a digit or a marker is a range's dash, not a sign
DATA_MARKER = re.compile(r"((?:(?<![\d>])[-−])?" + NUMBER.pattern.removeprefix("[-−]?")
                         + r")[^\d<]{0,12}"
                         r"<!--\s*data:\s*(\S+)\s+(\S+)(?:\s+x(\S+))?\s*-->", re.I)


def agrees(printed: str, value: float) -> bool:
    """Whether ``value`` prints as ``printed`` at the digits ``printed`` shows."""
    text = printed.replace("−", "-").replace(",", "")
    shown = float(text)
    mantissa = text.lower().split("e")[0]
    decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
    exp = int(text.lower().split("e")[1]) if "e" in text.lower() else 0
    half = 0.5 * 10.0 ** (exp - decimals)
    return abs(value - shown) <= half * (1 + 1e-9)


def _lookup(doc, key: str):
    for part in key.split("/"):
        doc = doc[int(part)] if isinstance(doc, list) else doc[part]
    return doc


@functools.lru_cache(maxsize=64)
def _read_json(file: Path, _mtime_ns: int):
    """A data file read once while it is unchanged (documents mark hundreds of figures in
    the same file)."""
    return json.loads(file.read_text())


def _read_value(file: Path, key: str) -> float:
    """The value KEY names in FILE: a JSON path, or for raw ``.txt`` output a regular
    expression that matches exactly once (its first group, else the whole match)."""
    if file.suffix != ".txt":
        return float(_lookup(_read_json(file, file.stat().st_mtime_ns), key))
    found = list(re.finditer(key, file.read_text(encoding="utf-8"), re.M))
    if len(found) != 1:
        raise ValueError(f"the pattern matches {len(found)} times, not once")
    raw = found[0].group(1) if found[0].re.groups else found[0].group(0)
    return float(raw.replace(",", "").replace("−", "-"))


def check_markers(paths: list[Path], root: Path = ROOT) -> tuple[int, list[str]]:
    """Every ``<!-- data: FILE KEY -->`` figure (FILE relative to ``root``): (checked,
    problems)."""
    checked, problems = 0, []
    for path in paths:
        text = path.read_text(encoding="utf-8")
        for m in DATA_MARKER.finditer(text):
            printed, file, key = m.group(1), m.group(2), m.group(3)
            scale = float(m.group(4)) if m.group(4) else 1.0
            line = text.count("\n", 0, m.start()) + 1
            where = f"{path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}:{line}"
            try:
                value = scale * _read_value(root / file, key)
            except (OSError, KeyError, IndexError, ValueError, TypeError, re.error) as exc:
                problems.append(f"{where}: {file} {key}: cannot read ({exc})")
                continue
            checked += 1
            if not agrees(printed, value):
                problems.append(f"{where}: prints {printed}, {file} {key} holds {value:.6g}")
    return checked, problems


def _between(text: str, begin: str, end: str) -> str | None:
    if begin not in text or end not in text:
        return None
    return text.split(begin, 1)[1].split(end, 1)[0].strip()


def _page(path: Path) -> str:
    """A page's text; '' when it is missing (then its sections are reported missing as a
    FAIL line, not a traceback)."""
    return path.read_text(encoding="utf-8") if path.is_file() else ""


@functools.cache
def _fair_rebuild() -> tuple[dict, str, str]:
    """The claims, docs/results.md's section and the README's section rebuilt from the kept
    runs of docs/results/fair (once per process: the statistics' bootstrap takes seconds)."""
    import fair_results as fr

    saved = fr.load_saved(FAIR)
    _doc, _doc2, claims, section, readme_section = fr.build(*saved, FAIR, ROOT / "docs" /
                                                           "results.md", ROOT / "README.md")
    return claims, section, readme_section


def _fair_section(which: int):
    return lambda: _fair_rebuild()[which]


def _first_difference(shown: str, text: str) -> str:
    a, b = shown.splitlines(), text.splitlines()
    first = next((i for i, (x, y) in enumerate(zip(a, b)) if x != y), min(len(a), len(b)))
    return (f"at its line {first + 1}: {(a[first] if first < len(a) else '(end)')[:160]!r} vs "
            f"{(b[first] if first < len(b) else '(end)')[:160]!r}")


def check_fair() -> tuple[int, list[str]]:
    """claims.json, and the data of the README's claims figure, against the claims rebuilt
    from docs/results/fair: (0, problems); the generated sections are in :data:`SECTIONS`."""
    if not (FAIR / "comparison.json").is_file():
        return 0, ["docs/results/fair/comparison.json: missing"]
    claims = _fair_rebuild()[0]
    committed = json.loads((FAIR / "claims.json").read_text()) if (FAIR / "claims.json").is_file() else None
    if committed != json.loads(json.dumps(claims)):
        return 0, ["docs/results/fair/claims.json: differs from the claims rebuilt from "
                   "runs.parquet (rerun benchmarks/fair_results.py --render)"]
    import fair_results as fr

    csv = fr.CLAIMS_FIGURE.with_suffix(".csv")
    if not csv.is_file() or csv.read_text() != fr.claims_figure_data(claims):
        return 0, [f"{csv.relative_to(ROOT)}: the README's claims figure's data differs from "
                   "claims.json (rerun benchmarks/fair_results.py --render)"]
    return 0, []


@functools.cache
def _full_state_section() -> str:
    import full_state_controllers as m

    return m.section(m.rows_from_csv(ROOT / "docs" / "results" / "full_state_controllers.csv"))


@functools.cache
def _identify_seeds_section() -> str:
    import identify_seeds_articulated as m

    path = ROOT / "benchmarks" / "results" / "identify_seeds_articulated.json"
    return m.seeds_table(json.loads(path.read_text()))


@functools.cache
def _tuning_curves_section() -> str:
    import tuning_curves as m

    return m.section(json.loads(m.DATA.read_text()))


@functools.cache
def _results_statistics_section() -> str:
    import pandas as pd
    import results as m

    doc = json.loads((ROOT / "docs" / "results" / "comparison.json").read_text())
    table = pd.read_parquet(ROOT / "docs" / "results" / "runs.parquet")
    kinds, seeds = doc["controllers"], doc["seeds"]
    table = table[table.controller.isin(kinds) & table.seed.isin(seeds)]
    return "\n".join(m.statistics_section(table, doc["scenarios"], kinds, seeds)[1])


@functools.cache
def _controller_evidence_section() -> str:
    import controller_evidence as m

    return m.section(m.claims())


@functools.cache
def _safety_evidence_section() -> str:
    import safety_evidence as m

    return m.section(m.claims())


#: sections a benchmark renders from its committed data: (document, begin marker, end
#: marker, the section rebuilt from the data, the data's file)
SECTIONS = (
    ("docs/results.md", "<!-- benchmarks/fair_results.py: begin (generated; rerun it, do not edit) -->",
     "<!-- benchmarks/fair_results.py: end -->", _fair_section(1), "docs/results/fair/runs.parquet"),
    ("README.md", "<!-- benchmarks/fair_results.py claims: begin (generated from "
     "docs/results/fair/claims.json) -->", "<!-- benchmarks/fair_results.py claims: end -->",
     _fair_section(2), "docs/results/fair/runs.parquet"),
    ("docs/results.md", "## What the statistics say: second type against first type",
     "## Figures", _results_statistics_section, "docs/results/runs.parquet"),
    ("docs/controllers.md", "<!-- full-state results: begin -->",
     "<!-- full-state results: end -->", _full_state_section,
     "docs/results/full_state_controllers.csv"),
    ("docs/controllers.md", "<!-- benchmarks/controller_evidence.py: begin (generated; rerun "
     "it, do not edit) -->", "<!-- benchmarks/controller_evidence.py: end -->",
     _controller_evidence_section, "docs/results/controllers_confirm.parquet"),
    ("docs/safety.md", "<!-- benchmarks/safety_evidence.py: begin (generated; rerun it, do "
     "not edit) -->", "<!-- benchmarks/safety_evidence.py: end -->",
     _safety_evidence_section, "benchmarks/results/safety_filter_cartpole_rail_hocbf_seeds200.csv"),
    ("docs/identify.md", "<!-- SEEDS -->", "<!-- SEEDS: end -->", _identify_seeds_section,
     "benchmarks/results/identify_seeds_articulated.json"),
    ("docs/results.md", "<!-- benchmarks/tuning_curves.py: begin (generated; rerun it, do not "
     "edit) -->", "<!-- benchmarks/tuning_curves.py: end -->", _tuning_curves_section,
     "docs/results/fair/tuning_curves.json"),
)


def check_sections(sections=SECTIONS, root: Path = ROOT) -> tuple[int, list[str]]:
    """Every section of :data:`SECTIONS` (in the documents under ``root``) against its
    rebuild from the data: (figures, problems)."""
    figures, problems = 0, []
    for doc, begin, end, build, data in sections:
        shown = _between(_page(root / doc), begin, end)
        if shown is None:
            problems.append(f"{doc}: no section {begin}"
                            + ("" if (root / doc).is_file() else ": the file is missing"))
            continue
        try:
            text = build().strip()
        except (OSError, ValueError, KeyError) as exc:
            problems.append(f"{doc}: cannot rebuild the section from {data} ({exc})")
            continue
        figures += len(NUMBER.findall(shown))
        if shown != text:
            problems.append(f"{doc}: the section {begin} differs from {data} "
                            + _first_difference(shown, text))
    return figures, problems


# -- the figures no check ties to data -----------------------------------------------------
#: a figure a reader may take for a result: a number not inside a word or a name (float64,
#: H200, mj_step2 are names), with its unit or "x" (7x, 0.49x, 12 ms, 42.4 %) allowed after;
#: both ends of a range (0-19) and of a count (4/20)
FIGURE = re.compile(r"(?<![A-Za-z_.\d])(?:(?<![-−])[-−])?\d+(?:,\d{3})*(?:\.\d+)?(?:e[-+]?\d+)?")
#: what is not prose: fenced blocks, HTML comments, code spans, link targets, bare links,
#: headings, an ordered list's numbers (each blanked, keeping the lines)
NOT_PROSE = (re.compile(r"^([ \t]*)(```|~~~).*?^\1\2[ \t]*$", re.S | re.M),
             re.compile(r"<!--.*?-->", re.S), re.compile(r"(`+).+?\1", re.S),
             re.compile(r"\]\([^)\s]*\)"), re.compile(r"<?https?://[^\s)>]+>?"),
             re.compile(r"^#{1,6} .*$", re.M), re.compile(r"^\s*\d+\.(?= )", re.M))


def unchecked_figures(path: Path, text: str, sections=SECTIONS,
                      root: Path = ROOT) -> list[tuple[int, str]]:
    """The figures of one document that no check ties to data: (line, figure) for every
    number in its prose and tables outside a marked figure and a generated section."""
    rel = path.relative_to(root).as_posix() if path.is_relative_to(root) else path.name
    hidden: list[tuple[int, int]] = []
    for doc, begin, end, *_ in sections:
        if doc == rel and begin in text and end in text:
            start = text.index(begin)
            hidden.append((start, text.index(end, start)))
    hidden += [(m.start(1), m.end()) for m in DATA_MARKER.finditer(text)]
    hidden += [m.span() for pattern in NOT_PROSE for m in pattern.finditer(text)]
    shown = list(text)
    for start, end in hidden:
        shown[start:end] = [c if c == "\n" else " " for c in text[start:end]]
    shown = "".join(shown)
    return [(shown.count("\n", 0, m.start()) + 1, m.group(0)) for m in FIGURE.finditer(shown)]


#: the most unchecked figures the documents may hold: lower it as figures get marked; a
#: document that adds an unmarked figure marks it or names it in its change. 4155 after issue
#: 56; raised to 4495 by the merge of issues 51, 53, 54 and 55, whose new pages and tables
#: (docs/rig.md 69 lines, docs/accelerator.md 16, docs/reliability.md 13, docs/safety.md 7)
#: are listed by this tool but not yet marked; lowered to 4262 as docs/rig.md, accelerator.md
#: and safety.md were marked and the controller and safety evidence became generated tables;
#: 4278 with docs/safety.md's six rows of the cart-pole refusing unadmitted starts (each
#: row's label: the rail's length and the seed range, as every row's); 4280 with the mpsc
#: QP's iteration cap (a setting) and the double cart-pole's refused seed (a label)
UNCHECKED_AT_MOST = 4280


def check_unchecked(paths: list[Path], root: Path = ROOT,
                    at_most: int | None = None) -> tuple[list[str], list[str], int]:
    """(one listing line per document line with unchecked figures, problems, how many
    figures)."""
    listing, count = [], 0
    for path in paths:
        rel = path.relative_to(root).as_posix() if path.is_relative_to(root) else str(path)
        by_line: dict[int, list[str]] = {}
        for line, figure in unchecked_figures(path, path.read_text(encoding="utf-8"),
                                              root=root):
            by_line.setdefault(line, []).append(figure)
        count += sum(map(len, by_line.values()))
        listing += [f"{rel}:{line}: {', '.join(f)}" for line, f in sorted(by_line.items())]
    limit = UNCHECKED_AT_MOST if at_most is None else at_most
    problems = [f"{count} unchecked figures, more than the {limit} allowed "
                f"(UNCHECKED_AT_MOST): mark the new ones with <!-- data: FILE KEY -->"] \
        if count > limit else []
    return listing, problems, count


def recompute(n: int) -> tuple[int, list[str]]:
    """Re-run ``n`` kept test runs from their tuned scenarios: (runs, problems)."""
    import pandas as pd

    import tspend

    rows = pd.read_parquet(FAIR / "runs.parquet")
    picked = rows.sample(n=min(n, len(rows)), random_state=0) if n < len(rows) else rows
    problems = []
    for r in picked.itertuples():
        scenario = FAIR / "tuned" / f"{r.scenario}-{r.controller}.toml"
        got = tspend.run(str(scenario), controller=r.controller, seed=int(r.seed),
                         keep_history=False).metrics
        for metric in fr_metrics():
            old, new = getattr(r, metric), got.get(metric)
            if old is None or new is None or (isinstance(old, float) and math.isnan(old)):
                continue
            if not math.isclose(old, new, rel_tol=1e-9, abs_tol=1e-15):
                problems.append(f"{r.scenario} {r.controller} seed {r.seed}: {metric} "
                                f"{old:.6g} kept, {new:.6g} today")
    return len(picked), problems


def fr_metrics() -> tuple[str, ...]:
    import fair_results as fr

    return fr.METRICS


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--recompute", type=int, default=0, metavar="N",
                    help="re-run N kept runs on today's code (0-10000; 0: none)")
    ap.add_argument("--quiet", action="store_true",
                    help="print the unchecked figures' count, not their list")
    args = ap.parse_args(argv)
    if not 0 <= args.recompute <= 10000:
        ap.error(f"--recompute: {args.recompute} is outside 0..10000")
    paths = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    marked, problems = check_markers(paths)
    problems += check_fair()[1]
    generated, more = check_sections()
    problems += more
    listing, more, unchecked = check_unchecked(paths)
    problems += more
    reran = 0
    if args.recompute:
        reran, more = recompute(args.recompute)
        problems += more
    if not args.quiet:
        print("unchecked figures (no data file ties them; FILE:LINE: figures):")
        print("\n".join(f"  {line}" for line in listing))
    for p in problems:
        print(f"  FAIL {p}")
    print(f"check_claims: {marked} marked figures and {generated} figures in generated "
          f"sections checked against their data"
          + (f", {reran} kept runs re-run on today's code" if args.recompute else "")
          + f"; {unchecked} unchecked figures listed (at most {UNCHECKED_AT_MOST}) on "
          f"{len(listing)} lines: {len(problems)} problem(s)")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
