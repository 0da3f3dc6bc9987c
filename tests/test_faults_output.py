"""What the project writes for people: no markup from a file name in a report, and no change to
a notebook user's matplotlib backend.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from flaair_analysis.discrepancy.case import DatasetCase
from flaair_model.model_io import load_model
from flaair_tools import discrepancy
from flaair_tools.discrepancy.report import write_validation
from test_discrepancy import write_case_csvs

EVIL = "<b onclick=x>run1"


@pytest.mark.slow  # the discrepancy command end to end, its report and figures rendered
def test_a_run_named_like_markup_reaches_the_discrepancy_report_as_text(tmp_path: Path) -> None:
    case = DatasetCase("named", "null", (), seed=5)
    csvs = write_case_csvs(case, load_model(), tmp_path / "csv")
    renamed = []
    for k, path in enumerate(csvs):
        target = path.with_name(f"{EVIL}{k} & 'q\".csv")
        path.rename(target)
        renamed.append(target)
    out = tmp_path / "out"
    assert discrepancy.main([str(p) for p in renamed] + ["--out", str(out)]) == 0
    page = (out / "report.html").read_text()
    assert "<b onclick" not in page and "&lt;b onclick=x&gt;run10 &amp; &#39;q&#34;" in page
    # the runs line and the tables that name runs
    assert page.count("&lt;b onclick=x&gt;") >= 4


def test_case_names_like_markup_reach_the_validation_page_as_text(tmp_path: Path) -> None:
    outcome = {
        "case": EVIL,
        "true": "<i>x</i>",
        "found": "none",
        "status": "no_discrepancy",
        "correct": True,
        "parameter_errors": {},
        "gap_reduction": {},
        "problems": ["<script>alert(1)</script>"],
        "elapsed_s": 1.0,
    }
    confusion = {
        "rows": ["<i>x</i>"],
        "columns": ["none"],
        "counts": [[1]],
        "correct": 1,
        "total": 1,
    }
    write_validation(tmp_path, [outcome], confusion, 1.0)
    page = (tmp_path / "validation.html").read_text()
    assert "<b onclick" not in page and "<script>" not in page and "<i>x</i>" not in page
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in page and "&lt;b onclick=x&gt;run1" in page


@pytest.mark.slow  # draws every report figure in a new interpreter
def test_drawing_figures_leaves_the_users_matplotlib_backend_alone(tmp_path: Path) -> None:
    """In a fresh interpreter, as in a notebook: the backend
    chosen before stays, pyplot is never imported.
    """
    src = Path(__file__).resolve().parents[1] / "src"
    script = textwrap.dedent(f"""
        import sys
        sys.path[:0] = {[str(p) for p in src.iterdir() if (p / "setup.py").exists()]!r}
        import matplotlib
        matplotlib.use("svg")
        import numpy as np
        from flaair_sensors import figures
        from flaair_tools.sweeps import sweep_report
        from flaair_tools.analysis import transition as transition_figure
        from flaair_tools.discrepancy import report
        from flaair_control.core import transition as tr
        t = np.arange(4000) / 20000.0
        rec = transition_figure.TransitionRecord(t, 10 * np.sin(2 * np.pi * 140 * t), t[::10],
                                                 np.ones(400), np.full(400, 140.0), np.zeros(400),
                                                 0)
        hp = tr.HilbertParams(band_hz=(40.0, 400.0), band_order=4, savgol_window_s=0.02,
                              savgol_order=2, edge_s=0.02)
        transition_figure.plot_transition(rec, tr.hilbert_analysis(rec.stroke_deg, 20000.0, hp),
                                          {str(tmp_path / "f.png")!r})
        assert matplotlib.get_backend() == "svg", matplotlib.get_backend()
        assert "matplotlib.pyplot" not in sys.modules
        print("ok")
    """)
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0 and result.stdout.strip() == "ok", result.stderr[-3000:]
    assert (tmp_path / "f.png").stat().st_size > 10_000
