"""Granular column collapse (geodem/cases/collapse.py, workflows/column_collapse.yaml,
workflows/column_collapse_mean.yaml).

Default suite: the reference law, the front detection and the mean over packings on hand-made
input, bad input (exit 2 naming the field), one small column (a = 2, 6 elements across, ~300
elements with the walls) run end to end: summary keys, pictures, GIF, VTK, the deposit at rest,
and the runout against Lube et al. (2005) within RUNOUT_TOLERANCE; and a tiny column (a = 1,
4 elements across) with two packings: two different runouts, summary = their mean.

Tolerance of the small run: 0.35. The shipped workflow has rotating elements with rolling
resistance 0.3 and restitution 0.9; at 6 elements across one grain more or less at the front is
10 % of L0 and packings of different seeds differ by up to 0.3 (docs/column_collapse.md;
measured 0.064 on the rough floor, 0.19 on the earlier frictional one). The test guards the measurement and gross failures (a column that does
not fall, a deposit scattered over the channel: errors of 0.6 to > 1) rather than the
validation target 0.15, which the averaged run below reports.

Slow (``-m slow``): workflows/column_collapse_mean.yaml, four aspect ratios x sixteen packings
on a rough floor (~29,000 elements, ~11 minutes on 2 cores), the max error of the mean runouts
against the target 0.15 (measured 0.126; the same packings run as four separate four-packing
models gave 0.147: docs/column_collapse.md)::

    PYTHONPATH=. python -m pytest tests/integration/test_column_collapse.py -m slow -q
"""
import json
import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from geodem.cli import app
from geodem.workflow import run_workflow
from geodem.cases.collapse import column_dims, deposit_front, lube_2005, packing_means
from geodem.workflow.schema import load_builtins

load_builtins()

ROOT = Path(__file__).resolve().parents[2]
WF = ROOT / "workflows" / "column_collapse.yaml"
WF_MEAN = ROOT / "workflows" / "column_collapse_mean.yaml"
RUNOUT_TOLERANCE = 0.35
RUNOUT_TARGET = 0.15  # the target for the mean over packings
KEYS = ("aspect_ratios", "runouts", "runout_rel_error", "runout_reference", "runout_rel_errors",
        "runout_lengths", "final_heights", "at_rest")

pytestmark = pytest.mark.usefixtures("one_numba_thread")


# ------------------------------------------------------------------ by hand
def test_lube_2005_law():
    assert lube_2005(1.0) == pytest.approx(1.2)
    assert lube_2005(2.3) == pytest.approx(2.76)
    assert lube_2005(8.0) == pytest.approx(1.9 * 4.0)
    np.testing.assert_allclose(lube_2005([0.5, 27.0]), [0.6, 1.9 * 9.0])


def test_column_dims_keep_the_narrower_side():
    assert column_dims(4.0, 0.03) == pytest.approx((0.03, 0.12))
    assert column_dims(0.5, 0.03) == pytest.approx((0.06, 0.03))


def test_deposit_front_excludes_detached_elements():
    r = np.full(7, 0.5)
    x = np.c_[[0.5, 1.5, 2.55, 3.6, 4.6, 9.0, 12.0], np.full(7, 0.5)]  # two ejected at the end
    front, members = deposit_front(x, r, link=0.25)
    assert front == pytest.approx(5.1)
    assert members.tolist() == [0, 1, 2, 3, 4]
    # a gap of 0.3 breaks the chain for link 0.25, not for link 0.5
    x2 = x.copy()
    x2[3:5, 0] += 0.3
    assert deposit_front(x2, r, link=0.25)[0] == pytest.approx(3.05)
    assert deposit_front(x2, r, link=0.5)[0] == pytest.approx(5.4)


def test_packing_means_by_hand():
    # two ratios x two packings, column j * 2 + i = packing j of ratio i
    per = [{"aspect_ratio": a, "runout": nr, "runout_length": 0.1 * nr, "final_height": h}
           for a, nr, h in [(1.0, 1.0, 0.03), (4.0, 5.0, 0.04),
                            (1.1, 1.4, 0.05), (4.2, 6.0, 0.06)]]
    m = packing_means(per, 2, 2)
    assert [v["runouts"] for v in m] == [[1.0, 1.4], [5.0, 6.0]]
    assert m[0]["runout"] == pytest.approx(1.2) and m[1]["runout"] == pytest.approx(5.5)
    assert m[0]["aspect_ratio"] == pytest.approx(1.05)
    assert m[1]["final_height"] == pytest.approx(0.05)
    assert m[0]["std"] == pytest.approx(0.4 / math.sqrt(2.0))  # sample std (ddof 1)
    assert m[0]["reference"] == pytest.approx(1.2 * 1.05)  # the law at the mean ratio
    assert m[0]["rel_error"] == pytest.approx(abs(1.2 - 1.26) / 1.26)
    assert m[1]["rel_error"] == pytest.approx(abs(5.5 - lube_2005(4.1)) / lube_2005(4.1))
    # one packing: the column itself, exactly
    one = packing_means(per[:2], 2, 1)
    assert [v["runout"] for v in one] == [1.0, 5.0] and one[0]["std"] == 0.0


# ------------------------------------------------------------------ bad input
@pytest.mark.parametrize("key,value,field", [
    ("model.aspect_ratios", "[0.1]", "model.aspect_ratios.0"),
    ("model.scale", "100", "model.scale"),
    ("steps.collapse.gif_column", "7", "steps[0].gif_column"),
    ("model.restitution", "1.5", "model.restitution"),
    ("model.rolling_friction", "-0.1", "model.rolling_friction"),
    ("model.packings", "0", "model.packings"),
    ("model.packings", "17", "model.packings"),
])
def test_bad_input_exits_2_naming_the_field(key, value, field):
    res = CliRunner().invoke(app, ["validate", str(WF), "--set", f"{key}={value}"])
    assert res.exit_code == 2, res.output
    text = " ".join(res.output.split())
    assert field in text.replace("[0]", ".0") or field in text, text
    assert "allowed" in text


# ------------------------------------------------------------------ a small run
@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("collapse")
    code, summary = run_workflow(
        WF, out / "run", sets=["model.aspect_ratios=[2.0]", "model.scale=0.6",
                               "steps.collapse.gif_frames=8", "outputs.observables.every=2000",
                               # two grains thrown up at the end of the flow fall at the
                               # standard damping's terminal speed (g / eta: 4.9 mm/s) and
                               # are still in the air after 100 standard balances (the
                               # default 40 stops them there too); 400 lets them land
                               "steps.collapse.settle_balances=400"],
        echo=False)
    return code, summary, out / "run"


def test_small_column_summary_and_files(small_run):
    code, s, run = small_run
    assert code == 0, s
    for key in KEYS:
        assert key in s, key
    assert s["at_rest"] is True  # measured: at rest, 128,650 steps in all
    assert len(s["aspect_ratios"]) == 1 and abs(s["aspect_ratios"][0] - 2.0) < 0.3
    for name in ("collapse_a2.png", "collapse_a2.vtp", "collapse_initial.vtp",
                 "collapse_runout.png", "collapse_history.png", "collapse_history.csv"):
        assert (run / name).stat().st_size > 0, name
    gif = run / "collapse.gif"
    assert gif.exists() and gif.read_bytes()[:6] in (b"GIF89a", b"GIF87a")
    from geodem.io.vtk import read_vtp

    v = read_vtp(run / "collapse_a2.vtp")
    assert v["Points"].shape[0] == len(v["radius"]) > 50
    assert np.all(v["column"] == 0)


def test_small_column_runout_against_lube_2005(small_run):
    code, s, run = small_run
    a = s["aspect_ratios"][0]
    ref = lube_2005(a)
    assert s["runout_reference"][0] == pytest.approx(ref)
    nr = s["runouts"][0]
    # the deposit spread well beyond the column, no higher than it stood
    assert nr > 0.3 * a
    info = json.loads((run / "summary.json").read_text())
    cols = info["results"]["collapse"]["columns"]
    assert cols[0]["final_height"] <= cols[0]["H0"] + 1e-9
    assert s["runout_rel_error"] == pytest.approx(abs(nr - ref) / ref)
    assert s["runout_rel_error"] < RUNOUT_TOLERANCE, (nr, ref)
    assert math.isfinite(s["runout_lengths"][0])


def test_two_packings_give_two_runouts_and_their_mean(tmp_path):
    # a = 1, 4 elements across, two packings (seeds 0 and 1), no pictures: a few seconds
    code, s = run_workflow(
        WF, tmp_path / "run", sets=["model.aspect_ratios=[1.0]", "model.scale=0.4",
                                    "model.packings=2", "steps.collapse.gif=false",
                                    "steps.collapse.plot=false", "outputs.observables.every=2000"],
        echo=False)
    assert code == 0, s
    assert s["packings"] == 2
    (two,) = s["runouts_per_packing"]
    assert len(two) == 2 and two[0] != two[1]  # different packings, different deposits
    assert s["runouts"][0] == pytest.approx(0.5 * (two[0] + two[1]))
    assert s["runout_std"][0] == pytest.approx(abs(two[0] - two[1]) / math.sqrt(2.0))
    ref = lube_2005(s["aspect_ratios"][0])
    assert s["runout_rel_error"] == pytest.approx(abs(s["runouts"][0] - ref) / ref)
    assert len(s["runout_rel_error_per_packing"]) == 2
    info = json.loads((tmp_path / "run" / "summary.json").read_text())
    cols = info["results"]["collapse"]["columns"]
    assert len(cols) == 2
    for c, nr in zip(cols, two):  # the per-packing errors are those of the columns
        assert c["runout"] == pytest.approx(nr)
    assert s["runout_rel_error_per_packing"] == pytest.approx([c["rel_error"] for c in cols])
    assert (tmp_path / "run" / "collapse_a1_p1.vtp").exists()


# ------------------------------------------------------------------ the validation
@pytest.mark.slow
def test_mean_of_sixteen_packings_against_lube_2005(tmp_path):
    # workflows/column_collapse_mean.yaml: sixteen packings of every column on a rough floor
    # (64 channels, ~29,000 elements, ~11 minutes on 2 cores)
    code, s = run_workflow(WF_MEAN, tmp_path / "run", sets=["steps.collapse.gif=false"],
                           echo=False)
    assert code == 0
    assert s["packings"] == 16 and len(s["runouts"]) == 4 and s["at_rest"] is True
    assert all(len(v) == 16 for v in s["runouts_per_packing"])
    # the mean runout grows with the aspect ratio
    assert np.all(np.diff(s["runouts"]) > 0)
    # measured (numba pool of 2 threads): 0.561 / 1.087 / 2.735 / 5.483 against the law's
    # 0.617 / 1.234 / 2.459 / 4.868, errors 9.1 / 11.9 / 11.2 / 12.6 %, max 0.126, with
    # standard errors of the means of 4.3 / 3.6 / 3.1 / 1.7 %: the margin to the target is
    # about one standard error (docs/column_collapse.md)
    assert s["runout_rel_error"] <= RUNOUT_TARGET
