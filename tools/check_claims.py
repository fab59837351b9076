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
* **Rendered sections.** The sections of :data:`SECTIONS` (docs/controllers.md's
  full-state results from ``docs/results/full_state_controllers.csv``, docs/identify.md's
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

``--recompute N``: re-runs N of the kept test runs (``runs.parquet``) from the committed
tuned scenarios (``tuned/SCENARIO-KIND.toml``) with today's code and fails when a metric
differs by more than 1e-9 relative: data that today's code no longer reproduces.

Exit 0 when every figure agrees; 1 otherwise, each difference named.
"""

from __future__ import annotations

import argparse
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


def _read_value(file: Path, key: str) -> float:
    """The value KEY names in FILE: a JSON path, or for raw ``.txt`` output a regular
    expression that matches exactly once (its first group, else the whole match)."""
    if file.suffix != ".txt":
        return float(_lookup(json.loads(file.read_text()), key))
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


def check_fair() -> tuple[int, list[str]]:
    """The generated sections against a rebuild from docs/results/fair: (figures, problems)."""
    import fair_results as fr

    problems: list[str] = []
    if not (FAIR / "comparison.json").is_file():
        return 0, ["docs/results/fair/comparison.json: missing"]
    page, readme = ROOT / "docs" / "results.md", ROOT / "README.md"
    saved = fr.load_saved(FAIR)
    _doc, _doc2, claims, section, readme_section = fr.build(*saved, FAIR, page, readme)
    figures = 0
    committed = json.loads((FAIR / "claims.json").read_text()) if (FAIR / "claims.json").is_file() else None
    if committed != json.loads(json.dumps(claims)):
        problems.append("docs/results/fair/claims.json: differs from the claims rebuilt from "
                        "runs.parquet (rerun benchmarks/fair_results.py --render)")
    for path, text, begin, end in ((page, section, fr.BEGIN, fr.END),
                                   (readme, readme_section, fr.README_BEGIN, fr.README_END)):
        shown = _between(_page(path), begin, end)
        if shown is None:
            problems.append(f"{path.relative_to(ROOT)}: no generated section ({begin})"
                            + ("" if path.is_file() else ": the file is missing"))
            continue
        figures += len(NUMBER.findall(shown))
        if shown != text.strip():
            a, b = shown.splitlines(), text.strip().splitlines()
            first = next((i for i, (x, y) in enumerate(zip(a, b)) if x != y), min(len(a), len(b)))
            problems.append(f"{path.relative_to(ROOT)}: the generated section differs from its "
                            f"data at its line {first + 1}: "
                            f"{(a[first] if first < len(a) else '(end)')[:160]!r} vs "
                            f"{(b[first] if first < len(b) else '(end)')[:160]!r}")
    return figures, problems


def _full_state_section() -> str:
    import full_state_controllers as m

    return m.section(m.rows_from_csv(ROOT / "docs" / "results" / "full_state_controllers.csv"))


def _identify_seeds_section() -> str:
    import identify_seeds_articulated as m

    path = ROOT / "benchmarks" / "results" / "identify_seeds_articulated.json"
    return m.seeds_table(json.loads(path.read_text()))


def _tuning_curves_section() -> str:
    import tuning_curves as m

    return m.section(json.loads(m.DATA.read_text()))


#: sections a benchmark renders from its committed data: (document, begin marker, end
#: marker, the section rebuilt from the data, the data's file)
SECTIONS = (
    ("docs/controllers.md", "<!-- full-state results: begin -->",
     "<!-- full-state results: end -->", _full_state_section,
     "docs/results/full_state_controllers.csv"),
    ("docs/identify.md", "<!-- SEEDS -->", "<!-- SEEDS: end -->", _identify_seeds_section,
     "benchmarks/results/identify_seeds_articulated.json"),
    ("docs/results.md", "<!-- benchmarks/tuning_curves.py: begin (generated; rerun it, do not "
     "edit) -->", "<!-- benchmarks/tuning_curves.py: end -->", _tuning_curves_section,
     "docs/results/fair/tuning_curves.json"),
)


def check_sections(sections=SECTIONS) -> tuple[int, list[str]]:
    """Every section of :data:`SECTIONS` against its rebuild from the data: (figures,
    problems)."""
    figures, problems = 0, []
    for doc, begin, end, build, data in sections:
        shown = _between(_page(ROOT / doc), begin, end)
        if shown is None:
            problems.append(f"{doc}: no section {begin}"
                            + ("" if (ROOT / doc).is_file() else ": the file is missing"))
            continue
        try:
            text = build().strip()
        except (OSError, ValueError, KeyError) as exc:
            problems.append(f"{doc}: cannot rebuild the section from {data} ({exc})")
            continue
        figures += len(NUMBER.findall(shown))
        if shown != text:
            a, b = shown.splitlines(), text.splitlines()
            first = next((i for i, (x, y) in enumerate(zip(a, b)) if x != y), min(len(a), len(b)))
            problems.append(f"{doc}: the section {begin} differs from {data} at its line "
                            f"{first + 1}: {(a[first] if first < len(a) else '(end)')[:160]!r} "
                            f"vs {(b[first] if first < len(b) else '(end)')[:160]!r}")
    return figures, problems


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
    args = ap.parse_args(argv)
    if not 0 <= args.recompute <= 10000:
        ap.error(f"--recompute: {args.recompute} is outside 0..10000")
    paths = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    marked, problems = check_markers(paths)
    generated, more = check_fair()
    problems += more
    rendered, more = check_sections()
    generated += rendered
    problems += more
    reran = 0
    if args.recompute:
        reran, more = recompute(args.recompute)
        problems += more
    for p in problems:
        print(f"  FAIL {p}")
    print(f"check_claims: {marked} marked figures and {generated} figures in generated "
          f"sections checked against their data"
          + (f", {reran} kept runs re-run on today's code" if args.recompute else "")
          + f": {len(problems)} problem(s)")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
