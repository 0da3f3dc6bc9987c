"""Render the published benchmark tables from the newest results file; check that they are.

Every figure the README and the guides publish comes from a results file that `make bench-full`
(or `make bench`, marked `subset`) wrote in `docs/results/`, never typed by hand. Each table sits
between two markers in its document::

    <!-- BEGIN results-table: readme -->
    ... rendered ...
    <!-- END results-table: readme -->

`BLOCKS` says which document holds which table and which figures it shows. Usage:

    python bench/results_table.py            # rewrite every block from the newest results file
    python bench/results_table.py --check    # exit 1 when a block differs from the rendering
    python bench/results_table.py --results docs/results/FILE.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
from dataclasses import dataclass
from pathlib import Path

from benchlib import REPO_ROOT, figure_from_row, met_text

RESULTS_DIR = REPO_ROOT / "docs" / "results"


@dataclass(frozen=True)
class Block:
    """One rendered table: its document, which figures (part names, name patterns), the baseline
    column or not.
    """

    name: str
    document: str
    parts: tuple[str, ...] = ()
    patterns: tuple[str, ...] = ()
    with_baseline: bool = True


# The README shows a few headline comparisons; each guide the whole of its benchmark part.
BLOCKS = (
    Block(
        "readme",
        "README.md",
        patterns=(
            r"^exactly right, ",
            r"^hidden-effect dataset cases right",
            r"^speedup numba",
            r"^composed loop RTF",
            r"^live: drive samples late or missing, with the health monitor minus without",
            r"^channel class right",
        ),
        with_baseline=False,
    ),
    Block("discrepancy", "docs/DISCREPANCY.md", parts=("bench_discrepancy",)),
    Block("truth", "docs/DISCREPANCY.md", parts=("bench_truth",)),
    Block("tables", "docs/TABLES.md", parts=("bench_tables",)),
    Block("health", "docs/HEALTH.md", parts=("bench_health",)),
)
MARKERS = "<!-- BEGIN results-table: {name} -->", "<!-- END results-table: {name} -->"
_RESULTS_NAME = re.compile(r"^\d{4}-\d{2}-\d{2}-[0-9a-f]+(?:-dirty)?(?:-subset)?\.json$")


class ResultsError(ValueError):
    """A results file or a document that cannot be rendered, with the reason."""


def newest_results(directory: Path | None = None) -> Path | None:
    """The newest results file in `directory` (default `RESULTS_DIR`) by the finish time it
    records, or None when there is none.
    """
    files = [p for p in (directory or RESULTS_DIR).glob("*.json") if _RESULTS_NAME.match(p.name)]
    if not files:
        return None
    return max(files, key=lambda p: (load_results(p)["finished_utc"], p.name))


def load_results(path: Path) -> dict:
    """A results file, checked for the fields the rendering reads."""
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ResultsError(f"{path}: not a readable results file ({exc})") from None
    need = ("mode", "commit", "date", "finished_utc", "machine", "wall_s", "figures")
    if not isinstance(doc, dict) or (missing := [k for k in need if k not in doc]):
        raise ResultsError(f"{path}: not a results file (missing {', '.join(missing) or 'all'})")
    return doc


def _value(value: float, unit: str) -> str:
    if value is None or math.isnan(value):
        return "not measured"
    if math.isinf(value):
        return f"{'-' if value < 0 else ''}infinite {unit}".strip()
    return f"{value:.4g} {unit}".strip()


def _cell(text: str, limit: int = 160) -> str:
    text = text.replace("|", "/").replace("\n", " ")
    return text if len(text) <= limit else text[: limit - 1] + "…"


def selected(block: Block, rows: list[dict]) -> list[dict]:
    """The results' figure rows a block shows, in the results' order."""
    return [
        r
        for r in rows
        if r.get("part") in block.parts or any(re.search(p, r["name"]) for p in block.patterns)
    ]


def render_block(block: Block, results: dict | None, source: str, link: str = "") -> str:
    """A block's Markdown (without its markers); `link`: the results file relative to the
    block's document (default `source`).
    """
    if results is None:
        return "No results file yet: `make bench-full` writes one in `docs/results/`."
    rows = selected(block, results["figures"])
    figures = [figure_from_row(r) for r in rows]
    compared = [f for f in figures if f.is_comparison]
    machine = results["machine"]
    head = (
        f"From [`{source}`]({link or source}): `{results['mode']}` at commit "
        f"`{results['commit']}` on "
        f"{results['date']}, {machine.get('cores')} cores ({machine.get('cpu_model')}, load "
        f"average {machine.get('load_average_end')} at the end), "
        f"{results['wall_s'] / 60:.1f} min wall. {sum(bool(f.met) for f in compared)} of "
        f"{len(compared)} comparisons shown here met."
    )
    lines = [head, ""]
    if block.with_baseline:
        lines += ["| figure | measured | target | met | beside it |", "|---|---|---|---|---|"]
    else:
        lines += ["| figure | measured | target | met |", "|---|---|---|---|"]
    for f in figures:
        cells = [_cell(f.name, 120), _value(f.value, f.unit), f.target, met_text(f)]
        if block.with_baseline:
            cells.append(_cell(f.baseline))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def replace_block(text: str, name: str, body: str, document: str) -> str:
    """The document's text with the named block's body replaced."""
    begin, end = (m.format(name=name) for m in MARKERS)
    if text.count(begin) != 1 or text.count(end) != 1 or text.index(begin) > text.index(end):
        raise ResultsError(f"{document}: needs exactly one '{begin}' ... '{end}' pair")
    head, rest = text.split(begin, 1)
    _, tail = rest.split(end, 1)
    return f"{head}{begin}\n{body}\n{end}{tail}"


def render_all(results_path: Path | None, root: Path = REPO_ROOT) -> dict[Path, tuple[str, str]]:
    """{document: (its text now, its text rendered)} for every document with a block."""
    results = load_results(results_path) if results_path is not None else None
    source = results_path.relative_to(root).as_posix() if results_path is not None else ""
    out: dict[Path, tuple[str, str]] = {}
    for block in BLOCKS:
        path = root / block.document
        if not path.exists():
            raise ResultsError(f"{block.document}: no such document")
        now = out[path][1] if path in out else path.read_text()
        link = os.path.relpath(root / source, path.parent) if source else ""
        rendered = replace_block(
            now, block.name, render_block(block, results, source, link), block.document
        )
        out[path] = (out[path][0] if path in out else now, rendered)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--check", action="store_true", help="exit 1 when a rendered block differs; write nothing"
    )
    parser.add_argument(
        "--results", type=Path, help="the results file (default: the newest in docs/results/)"
    )
    args = parser.parse_args(argv)
    try:
        path = args.results.resolve() if args.results else newest_results()
        documents = render_all(path)
    except ResultsError as exc:
        print(f"results_table: {exc}", file=sys.stderr)
        return 2
    stale = [p for p, (now, rendered) in documents.items() if now != rendered]
    if args.check:
        for p in stale:
            print(
                f"results_table: {p.relative_to(REPO_ROOT)} differs from its rendering; run "
                "python bench/results_table.py",
                file=sys.stderr,
            )
        return 1 if stale else 0
    for p in stale:
        p.write_text(documents[p][1])
        print(f"rendered {p.relative_to(REPO_ROOT)}")
    print(f"from {path.relative_to(REPO_ROOT) if path else 'no results file'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
