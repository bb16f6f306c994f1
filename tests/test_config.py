"""Scenarios and instruments as data: TOML/JSON round trip, strict schema, stable content hash; study files."""
import json
import subprocess
import sys
import tomllib

import pytest

from workbench.config import ConfigError, content_hash, from_dict, load_config, save_config, to_dict, with_value
from workbench.scenario import Instrument, Scenario, dataset_parts
from workbench.studies.study import load_study, parse_study


def _changed_scenario() -> Scenario:
    s = Scenario(experiment="rigid_motion", seed=7)
    for path, value in (("rig.lens", "thin"), ("render.spp", 16), ("render.electrons_per_grey", 12.5),
                        ("target.print_scale_error", 0.005), ("target.bow_sag_mm", 0.4),
                        ("drift.translation_um_per_state", (1.0, 0.0, -0.5)), ("motion.return_to_zero", True),
                        ("lens.k3", -0.2)):
        s = with_value(s, path, value)
    return s


@pytest.mark.parametrize("suffix", [".toml", ".json"])
def test_scenario_and_instrument_round_trip_exactly_through_files(tmp_path, suffix):
    scenario = _changed_scenario()
    instrument = Instrument(subset_px=41, calibration_model="pinhole", prefilter_sigma_px=0.8)
    save_config(scenario, tmp_path / f"s{suffix}")
    save_config(instrument, tmp_path / f"i{suffix}")
    assert load_config(Scenario, tmp_path / f"s{suffix}") == scenario
    assert load_config(Instrument, tmp_path / f"i{suffix}") == instrument
    # the TOML we write is TOML for any reader: the standard library's parser gives the same mapping
    if suffix == ".toml":
        assert tomllib.loads((tmp_path / "s.toml").read_text()) == json.loads(json.dumps(to_dict(scenario)))


def test_content_hash_is_stable_across_processes_and_changes_with_any_value():
    scenario = _changed_scenario()
    code = ("from workbench.config import with_value, content_hash\nfrom workbench.scenario import Scenario\n"
            "s = Scenario(experiment='rigid_motion', seed=7)\n"
            "for p, v in (('rig.lens','thin'),('render.spp',16),('render.electrons_per_grey',12.5),"
            "('target.print_scale_error',0.005),('target.bow_sag_mm',0.4),"
            "('drift.translation_um_per_state',(1.0,0.0,-0.5)),('motion.return_to_zero',True),('lens.k3',-0.2)):\n"
            "    s = with_value(s, p, v)\nprint(content_hash(s))")
    other = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert other == content_hash(scenario)
    # an integer given for a float parameter is the same content
    assert content_hash(with_value(scenario, "render.read_noise_grey", 2)) == \
        content_hash(with_value(scenario, "render.read_noise_grey", 2.0))
    assert content_hash(with_value(scenario, "render.read_noise_grey", 1.0 + 1e-9)) != content_hash(scenario)


def test_defaults_are_left_out_of_the_hash_so_a_new_parameter_off_by_default_keeps_old_hashes():
    from workbench.config import canonical_json

    text = canonical_json(Scenario())
    assert json.loads(text) == {"type": "Scenario", "schema": 1}
    changed = json.loads(canonical_json(with_value(Scenario(), "rig.focus_offset_mm", 2.0)))
    assert changed["rig"] == {"focus_offset_mm": 2.0}


def test_dataset_parts_hash_only_the_sections_that_change_their_images():
    base = Scenario(experiment="rigid_motion")
    stage = with_value(base, "motion.stage_scale_error", 1e-3)
    board = with_value(base, "target.print_scale_error", 1e-3)
    parts, parts_stage, parts_board = dataset_parts(base), dataset_parts(stage), dataset_parts(board)
    assert parts["calibration"][0] == parts_stage["calibration"][0]      # the stage error reuses the board renders
    assert parts["states"][0] != parts_stage["states"][0]
    assert parts["states"][0] == parts_board["states"][0]               # the board error reuses the state renders
    assert parts["calibration"][0] != parts_board["calibration"][0]


@pytest.mark.parametrize("data, message", [
    ({"render": {"spq": 3}}, r"render\.spq: unknown key"),
    ({"rendr": {}}, r"rendr: unknown key"),
    ({"render": {"spp": "many"}}, r"render\.spp: expected an integer, got 'many'"),
    ({"render": {"spp": 2.5}}, r"render\.spp: expected an integer"),
    ({"render": {"read_noise_grey": True}}, r"render\.read_noise_grey: expected a number"),
    ({"render": {"read_noise_grey": -1.0}}, r"render\.read_noise_grey: must be >= 0"),
    ({"render": {"read_noise_grey": float("nan")}}, r"render\.read_noise_grey: must be finite"),
    ({"rig": {"lens": "fisheye"}}, r"rig\.lens: must be one of 'pinhole', 'thin'"),
    ({"drift": {"translation_um_per_state": [1.0, 2.0]}}, r"drift\.translation_um_per_state: expected a list of 3"),
    ({"render": 5}, r"render: expected a table of keys"),
])
def test_scenario_schema_refuses_bad_keys_and_values_naming_the_key(data, message):
    with pytest.raises(ConfigError, match=message):
        from_dict(Scenario, data)


def test_a_bad_config_file_is_refused_naming_the_file_and_key(tmp_path):
    path = tmp_path / "scenario.toml"
    path.write_text("[render]\nspp = 'lots'\n")
    with pytest.raises(ConfigError, match=r"scenario\.toml: render\.spp: expected an integer"):
        load_config(Scenario, path)
    path.write_text("[render\nspp = 3\n")
    with pytest.raises(ConfigError, match=r"scenario\.toml: not valid TOML"):
        load_config(Scenario, path)
    with pytest.raises(ConfigError, match=r"even\.toml: no such file"):
        load_config(Scenario, tmp_path / "even.toml")


def test_instrument_cross_checks_name_the_field():
    with pytest.raises(ConfigError, match=r"subset_px must be odd, got 32"):
        from_dict(Instrument, {"subset_px": 32})


# ------------------------------------------------------------------------------------------------------------
STUDY = """
[study]
name = "tiny"
repeats = 2
[scenario]
experiment = "dic2d"
[[axis]]
name = "noise"
parameter = "scenario.render.read_noise_grey"
values = [1.0, 2.0]
[[axis]]
name = "subset"
parameter = "instrument.subset_px"
values = [21, 31, 41]
"""


def test_a_factorial_study_expands_to_every_combination_times_every_seed(tmp_path):
    path = tmp_path / "study.toml"
    path.write_text(STUDY)
    study = load_study(path)
    cases = study.expand()
    assert len(cases) == 2 * 3 * 2
    assert len({c.hash for c in cases}) == len(cases)
    assert {(c.labels["noise"], c.labels["subset"], c.seed) for c in cases} == \
        {(n, s, seed) for n in (1.0, 2.0) for s in (21, 31, 41) for seed in (0, 1)}
    case = next(c for c in cases if c.labels == {"noise": 2.0, "subset": 31, "repeat": 1})
    assert (case.scenario.render.read_noise_grey, case.instrument.subset_px, case.scenario.seed) == (2.0, 31, 1)


@pytest.mark.parametrize("edit, message", [
    (lambda t: t.replace("repeats = 2", "repeats = 2\nrepeat = 3"), r"study\.toml: study\.repeat: unknown key"),
    (lambda t: t.replace("repeats = 2", "repeats = 'two'"), r"study\.toml: study\.repeats: expected int"),
    (lambda t: t.replace("scenario.render.read_noise_grey", "scenario.render.read_noise"),
     r"study\.toml: axis\[0\] \(noise\): scenario\.render\.read_noise: no such parameter"),
    (lambda t: t.replace("scenario.render.read_noise_grey", "scenario.noise.read_noise_grey"),
     r"study\.toml: axis\[0\] \(noise\): scenario\.noise\.read_noise_grey: no such parameter in Scenario "
     r"\(did you mean render\.read_noise_grey\?\)"),
    (lambda t: t.replace("values = [21, 31, 41]", "values = [21, 'big']"),
     r"study\.toml: axis\[1\] \(subset\): instrument\.subset_px: expected an integer, got 'big'"),
    (lambda t: t.replace('experiment = "dic2d"', 'experiment = "dic2d"\nsed = 3'), r"study\.toml: scenario\.sed: unknown key"),
    (lambda t: t.replace("[[axis]]\nname = \"noise\"", "[[axis]]\nnme = \"noise\"", 1), r"study\.toml: axis\[0\]\.nme: unknown key"),
    (lambda t: t + "\n[extra]\n", r"study\.toml: extra: unknown key"),
    (lambda t: t.replace("repeats = 2", "repeats = 2\nmetrics = ['random_error']"),
     r"study\.toml: study\.metrics: 'random_error' is not a metric of the dic2d experiment"),
])
def test_bad_study_files_are_refused_naming_the_file_and_key(tmp_path, edit, message):
    path = tmp_path / "study.toml"
    path.write_text(edit(STUDY))
    with pytest.raises(ConfigError, match=message):
        load_study(path)


def test_cases_mode_study_sets_listed_parameters():
    study = parse_study({"study": {"mode": "cases", "seeds": [3, 5]}, "scenario": {"experiment": "rigid_motion"},
                         "case": [{"name": "base"},
                                  {"name": "scale", "set": {"scenario.target.print_scale_error": 0.005,
                                                            "instrument.subset_px": 41}}]}, "s.toml")
    cases = study.expand()
    assert study.dims == ("case", "repeat")
    assert [(c.labels["case"], c.seed) for c in cases] == [("base", 3), ("base", 5), ("scale", 3), ("scale", 5)]
    scaled = cases[2]
    assert (scaled.scenario.target.print_scale_error, scaled.instrument.subset_px) == (0.005, 41)
    assert cases[0].scenario.target.print_scale_error == 0.0


def test_a_case_the_experiment_cannot_render_is_refused_before_any_work(tmp_path):
    path = tmp_path / "rm.toml"
    path.write_text("[study]\nmode = 'cases'\n[scenario]\nexperiment = 'rigid_motion'\n"
                    "[[case]]\nname = 'deep'\nset = { 'scenario.render.bit_depth' = 16 }\n")
    with pytest.raises(ConfigError, match=r"rm\.toml: case case = deep: scenario\.render\.bit_depth = 16: the "
                                          r"rigid-motion renders are 8-bit images"):
        load_study(path)
    path.write_text("[study]\nmode = 'cases'\n[scenario]\nexperiment = 'rigid_motion'\n"
                    "[[case]]\nname = 'odd'\nset = { 'scenario.motion.step_mm' = 3.0 }\n")
    with pytest.raises(ConfigError, match=r"max_mm = 10.0 must be a whole number of steps of 3.0 mm"):
        load_study(path)


def test_a_case_measured_on_other_renderers_images_is_another_case():
    """The case hash carries the renderers that are not Mitsuba (the deterministic board and speckle renderers
    make other images): rigid-motion cases pinned to Mitsuba keep the hash the formula gave before the renderer
    choices existed (computed here from its two parts by hand), default (auto) cases get a new one, and 2-D
    cases are untouched."""
    import hashlib

    from workbench.scenario import case_hash

    def old_hash(scenario, instrument):
        text = json.dumps({"scenario": content_hash(scenario), "instrument": content_hash(instrument)},
                          sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    instrument = Instrument()
    mitsuba = from_dict(Scenario, {"experiment": "rigid_motion",
                                   "render": {"board_renderer": "mitsuba", "speckle_renderer": "mitsuba"}})
    auto = from_dict(Scenario, {"experiment": "rigid_motion"})
    dic2d = from_dict(Scenario, {"experiment": "dic2d"})
    # pinned to Mitsuba: the hash the same scenario had before the renderer choices existed (= no such keys)
    assert case_hash(mitsuba, instrument) == old_hash(auto, instrument)
    assert case_hash(dic2d, instrument) == old_hash(dic2d, instrument)
    assert case_hash(auto, instrument) != old_hash(auto, instrument)
    speckle_only = with_value(mitsuba, "render.speckle_renderer", "auto")
    assert case_hash(speckle_only, instrument) not in (case_hash(mitsuba, instrument), case_hash(auto, instrument))
    states = dict(dataset_parts(auto))["states"][1]
    assert states["speckle_renderer"].startswith("polygon-quadrature")
    assert dataset_parts(mitsuba)["states"][0] != dataset_parts(auto)["states"][0]
