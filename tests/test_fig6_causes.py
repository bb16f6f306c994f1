"""The Fig 6 explanation's scoring: tolerances, linear extrapolation of single causes, calibration consistency.

Synthetic case records with known curves; the expected verdicts are computed here by hand.
"""
import json

import numpy as np
import pytest

from workbench.studies.fig6_causes import paper_at, write_fig6_report
from workbench.studies.study import parse_study

STAGE = np.arange(1.0, 11.0)


def _study():
    return parse_study({"study": {"mode": "cases", "seeds": [0]},
                        "scenario": {"experiment": "rigid_motion", "rig": {"scale": 0.25}},
                        "case": [{"name": "perfect world"},
                                 {"name": "scale", "set": {"scenario.target.print_scale_error": -0.004}},
                                 {"name": "roll", "set": {"scenario.motion.stage_rotation_urad_per_mm": [0.0, 0.0, 40.0]}},
                                 {"name": "both", "set": {"scenario.target.print_scale_error": -0.005,
                                                          "scenario.motion.stage_scale_error": 0.001}},
                                 {"name": "bent", "set": {"scenario.target.bow_sag_mm": 1.0}}]}, "fig6.toml")


def _record(name, mean, std, cal_rms):
    return {"status": "ok", "hash": name, "labels": {"case": name, "repeat": 0},
            "metrics": {"mean_error_um": list(mean), "std_um": list(std), "mean_error_truth_um": list(mean),
                        "points_fraction": [1.0] * 10, "reference_rms_um": 1.0, "calibration_rms_px": cal_rms,
                        "triangulated_scale_error": 0.0},
            "dims": {k: ["stage_mm"] for k in ("mean_error_um", "std_um", "mean_error_truth_um", "points_fraction")},
            "coords": {"stage_mm": STAGE.tolist()}}


def test_verdicts_follow_the_tolerances_and_the_hand_computed_extrapolation(tmp_path):
    pm, ps = paper_at(STAGE)
    floor = np.full(10, 0.5)
    records = [_record("perfect world", 0.0 * STAGE, floor, 0.04),
               _record("scale", 4.0 * STAGE, floor, 0.04),                           # mean only, 40 µm at 10 mm
               _record("roll", 0.0 * STAGE, np.hypot(floor, 0.8 * STAGE), 0.04),      # std only
               _record("both", pm * 1.1, ps * 0.8, 0.04),                             # inside 20 % / 30 %
               _record("bent", pm, ps, 0.30)]                                         # curves, but a bad calibration
    result = write_fig6_report(_study(), tmp_path, records, {})
    by_case = {s["case"]: s for s in result["summaries"]}
    assert by_case["both"]["matches_paper"] and not by_case["scale"]["matches_paper"]
    # the scale case: 40 µm at 10 mm for e = -0.004, so the paper's 50.9 µm needs e = -0.004 * 50.9 / 40
    scale = next(v for v in result["single_causes"] if v["case"] == "scale")
    assert scale["value_for_paper_mean"] == pytest.approx(-0.004 * 50.9 / 40.0, rel=1e-9)
    assert scale["std_at_that_value_um"] == pytest.approx(0.5, rel=1e-9) and scale["verdict"].startswith("mean only")
    # the roll case grows the std by hypot(0.5, 8) - hypot(0.5, 0.8) µm from 1 to 10 mm; the paper's 10.3 - 1.9
    roll = next(v for v in result["single_causes"] if v["case"] == "roll")
    growth = np.hypot(0.5, 8.0) - np.hypot(0.5, 0.8)
    assert roll["value_for_paper_mean"] is None and roll["verdict"].startswith("std only")
    assert roll["value_for_paper_growth"] == pytest.approx([0.0, 0.0, 40.0 * (10.3 - 1.9) / growth], rel=1e-9)
    # the bent board adds sqrt(0.30^2 - 0.04^2) / 0.25 = 1.19 px at full resolution: more than the paper's 0.35
    assert by_case["bent"]["calibration_misfit_full_res_px"] == pytest.approx(np.sqrt(0.30 ** 2 - 0.04 ** 2) / 0.25)
    assert result["matching"] == ["both"] and result["curves_only"] == ["bent"]
    assert json.loads((tmp_path / "fig6_causes.json").read_text())["best"][0] == "both"
    text = (tmp_path / "fig6_causes.md").read_text()
    assert "![Fig 6](fig6_causes.png)" in text and (tmp_path / "fig6_causes.png").stat().st_size > 10_000


def test_the_study_writes_one_html_report_with_fig6_and_the_study_figures(tmp_path):
    """One generated HTML per study folder: Fig 6, the verdicts and the study's own figures are in report.html,
    and no second HTML (fig6_causes.html) is written beside it."""
    pm, ps = paper_at(STAGE)
    records = [_record(name, pm, ps, 0.04) for name in ("perfect world", "scale", "roll", "both", "bent")]
    study_figure = ("study figure: mean error", "c3R1ZHk=")          # base64 of b"study"
    write_fig6_report(_study(), tmp_path, records, {}, [study_figure], ["study line: 5 cases"])
    html = (tmp_path / "report.html").read_text()
    assert "Fig 6: paper vs simulated causes" in html and "study figure: mean error" in html
    assert "c3R1ZHk=" in html and "study line: 5 cases" in html
    assert sorted(p.name for p in tmp_path.glob("*.html")) == ["report.html"]


def test_the_report_says_whether_the_explanation_changes_at_another_resolution(tmp_path):
    """Against the same study's result the explanation "does not change" (0 cases change); against a result in
    which the "roll" case reproduced Fig 6 (flipped here by hand) it "changes" and names that case."""
    pm, ps = paper_at(STAGE)
    records = [_record(name, pm * (1.3 if name != "scale" else 1.0), ps, 0.04)
               for name in ("perfect world", "scale", "roll", "both", "bent")]
    for name in "abc":
        (tmp_path / name).mkdir()
    same = write_fig6_report(_study(), tmp_path / "a", records, {})
    write_fig6_report(_study(), tmp_path / "b", records, {}, compare=(same, 1.0))
    text = (tmp_path / "b" / "fig6_causes.md").read_text()
    assert "**The explanation does not change**: 0 of 5 cases change their verdict" in text
    flipped = json.loads(json.dumps(same))
    roll = next(s for s in flipped["summaries"] if s["case"] == "roll")
    assert roll["matches_paper"] is False
    roll["matches_paper"] = True
    write_fig6_report(_study(), tmp_path / "c", records, {}, compare=(flipped, 1.0))
    text = (tmp_path / "c" / "fig6_causes.md").read_text()
    assert "**The explanation changes**: 1 of 5 cases change their verdict (roll)" in text
    assert "(scale 0.25 here, 1 in the other study)" in text


def test_a_cause_whose_states_the_instrument_refused_is_ruled_out_as_such(tmp_path):
    """A single cause whose 10 mm state was not measured (NaN: the instrument refused it) is not extrapolated
    from NaN: its verdict says which check travel is missing and why it rules the cause out at that size."""
    pm, ps = paper_at(STAGE)
    refused_mean = np.where(STAGE >= 4, np.nan, pm)
    records = [_record("perfect world", 0 * pm, 0 * ps, 0.04), _record("scale", pm, ps, 0.04),
               _record("roll", refused_mean, ps, 0.04), _record("both", pm, ps, 0.04), _record("bent", pm, ps, 0.04)]
    result = write_fig6_report(_study(), tmp_path, records, {})
    roll = next(v for v in result["single_causes"] if v["case"] == "roll")
    assert roll["verdict"].startswith("not measured at 5, 10 mm: ")
    assert "ruled out at this size" in roll["verdict"]
