"""Settings own their defaults and their choices (the library resolves them, Python passes what its
caller gave), errors name the setting as Python spells it (never a CLI flag), and dicts of settings
go through the library's parsers."""
import math
import re

import numpy as np
import pytest

import sonoslice


# ---- registration --------------------------------------------------------------------------------
def test_registration_settings_choose_the_optimizer_per_metric():
    s = sonoslice.RegistrationSettings()
    assert s.metric == sonoslice.RegistrationMetric.ncc and s.optimizer is None
    assert s.resolved().optimizer == sonoslice.RegistrationOptimizer.lm
    for metric, optimizer in (("ssd", "lm"), ("ncc", "lm"), ("lncc", "bobyqa"), ("mi", "bobyqa"), ("lc2", "bobyqa")):
        m = sonoslice.RegistrationMetric[metric]
        assert str(sonoslice._ext.default_optimizer(m)) == optimizer
        try:
            resolved = sonoslice.RegistrationSettings(metric=m).resolved()
        except ValueError as e:  # a build without NLopt says so, naming the setting
            assert "optimizer bobyqa" in str(e) and "built without NLopt" in str(e)
            continue
        assert str(resolved.optimizer) == optimizer
    given = sonoslice.RegistrationSettings(metric=sonoslice.RegistrationMetric.ssd,
                                           optimizer=sonoslice.RegistrationOptimizer.gn)
    assert given.resolved().optimizer == sonoslice.RegistrationOptimizer.gn


def test_registration_settings_choose_the_pyramid_per_metric():
    s = sonoslice.RegistrationSettings()
    assert s.pyramid is None and "pyramid=None" in repr(s)
    for metric, levels in (("ssd", [8, 4, 2, 1]), ("ncc", [8, 4, 2, 1]), ("lncc", [8, 4, 2, 1]),
                           ("mi", [8, 4, 2, 1]), ("lc2", [2, 1])):
        m = sonoslice.RegistrationMetric[metric]
        assert sonoslice._ext.default_pyramid(m) == levels
        assert sonoslice.RegistrationSettings(metric=m, optimizer=sonoslice.RegistrationOptimizer.nelder_mead
                                              if metric in ("lncc", "mi", "lc2") else None).pyramid is None
    given = sonoslice.RegistrationSettings(pyramid=[4, 1])
    assert given.pyramid == [4, 1] and given.resolved().pyramid == [4, 1] and "pyramid=[4, 1]" in repr(given)
    assert sonoslice.RegistrationSettings().resolved().pyramid == [8, 4, 2, 1]


def test_registration_settings_cap_the_automatic_starts_per_metric():
    for metric, most in (("ssd", 48), ("ncc", 48), ("lncc", 12), ("mi", 12), ("lc2", 12)):
        assert sonoslice._ext.default_max_starts(sonoslice.RegistrationMetric[metric]) == most


def test_registration_cost_is_lowest_where_the_frame_was_made(phantom, poses):
    ct, _ = phantom
    probe = sonoslice.Probe.linear(40, 32, 0.5)
    frames = sonoslice.Slicer(ct, probe).slice(poses[:3])
    moved = poses[:3].copy()
    moved[:, :3, 3] += 2.0
    for metric in ("ssd", "ncc"):
        at_truth = sonoslice.registration_cost(ct, probe, frames, poses[:3], metric=metric)
        off = sonoslice.registration_cost(ct, probe, frames, moved, metric=metric, level=2)
        assert at_truth.shape == (3,) and np.all(at_truth < 1e-6) and np.all(off > at_truth)
    with pytest.raises(ValueError, match="^poses: expected one per frame"):
        sonoslice.registration_cost(ct, probe, frames, poses[:2])
    with pytest.raises(ValueError, match="^pyramid: level 0 is outside 1..64"):
        sonoslice.registration_cost(ct, probe, frames, poses[:3], level=0)
    with pytest.raises(ValueError, match="^frames: expected"):
        sonoslice.registration_cost(ct, probe, frames[:, :5], poses[:3])


@pytest.mark.parametrize("kwargs, message", [
    (dict(starts=0), "starts 0: must be at least 1"),
    (dict(search_trans_mm=math.nan), "search_trans_mm nan: must be a distance from 0 to 1e9 mm"),
    (dict(pyramid=[4, 0]), "pyramid 4,0: expected block sizes from 1 to 64"),
    (dict(pyramid=[1, 2, 4]), "pyramid 1,2,4: the block sizes must decrease, coarse to fine"),
    (dict(smoothness=-1.0, mode=sonoslice.RegistrationMode.smooth_sweep), "smoothness -1: must be a finite weight"),
    (dict(smoothness=0.5), "smoothness: applies to mode smooth-sweep"),
    (dict(metric=sonoslice.RegistrationMetric.mi, optimizer=sonoslice.RegistrationOptimizer.gn),
     "metric mi has no analytic derivatives: use optimizer bobyqa or nelder-mead"),
])
def test_registration_errors_name_the_setting(kwargs, message):
    with pytest.raises(ValueError, match="^" + message) as e:
        sonoslice.RegistrationSettings(**kwargs)
    assert "--" not in str(e.value)


def test_register_passes_only_what_it_is_given(phantom, poses):
    ct, _ = phantom
    probe = sonoslice.Probe.linear(24, 20, 1.0)
    frames = sonoslice.Slicer(ct, probe).slice(poses[:2])
    refined, report = sonoslice.register(ct, probe, frames, poses[:2], pyramid=(2, 1))
    # The report says what ran: the library's defaults and its choice of optimiser.
    assert (report["metric"], report["optimizer"], report["mode"], report["starts"]) == ("ncc", "lm", "per-frame", "auto")
    assert "smoothness" not in report and "correction" not in report and refined.shape == (2, 4, 4)
    settings = sonoslice.RegistrationSettings(pyramid=[2, 1], metric=sonoslice.RegistrationMetric.ssd)
    same, report = sonoslice.register(ct, probe, frames, poses[:2], settings=settings)
    assert report["metric"] == "ssd" and report["optimizer"] == "lm"
    with pytest.raises(TypeError, match="not both"):
        sonoslice.register(ct, probe, frames, poses[:2], settings=settings, starts=2)
    with pytest.raises(ValueError, match="^mode 'sweep': expected 'per-frame', 'rigid-sweep', 'smooth-sweep' or 'calibration'"):
        sonoslice.register(ct, probe, frames, poses[:2], mode="sweep")
    # A keyword of the wrong type is named, as a wrong value is (not nanobind's generic error).
    for kwargs, error, message in ((dict(starts=2.5), ValueError, "^starts 2.5: expected a whole number"),
                                   (dict(starts=math.nan), ValueError, "^starts nan: expected a whole number"),
                                   (dict(seed="x"), TypeError, "^seed: expected an integer"),
                                   (dict(search_rot_deg="x"), TypeError, "^search_rot_deg: expected numbers"),
                                   (dict(search_trans_mm=[1, 2]), ValueError, "^search_trans_mm: expected 1 numbers")):
        with pytest.raises(error, match=message):
            sonoslice.register(ct, probe, frames, poses[:2], **kwargs)


# ---- simulation -----------------------------------------------------------------------------------
def test_simulation_frequency_is_the_presets_else_5_mhz():
    assert sonoslice.SimulationSettings().frequency_mhz is None
    assert sonoslice.SimulationSettings().resolved().frequency_mhz == 5.0
    assert sonoslice.SimulationSettings(preset="lus").resolved().frequency_mhz == 6.5
    assert sonoslice.SimulationSettings(preset="lus", frequency_mhz=3.0).resolved().frequency_mhz == 3.0


def test_simulator_reports_what_the_library_chose(phantom):
    ct, labels = phantom
    sim = sonoslice.Simulator(ct, sonoslice.Probe.workload("W1"))
    assert sim.frequency == 5.0 and sim.kind == "ct" and sim.seed == 0
    assert sim.settings.output == sonoslice.SimulationOutput.bmode and sim.settings.dynamic_range_db == 60
    assert sonoslice.Simulator(labels, "lus", tissues=sonoslice.phantom_tissues()).kind == "labels"


@pytest.mark.parametrize("kwargs, message", [
    (dict(preset="nope"), "preset nope: unknown (presets: abdominal"),
    (dict(frequency_mhz=0.0), "frequency_mhz: frequency 0 MHz must be in [0.1, 100]"),
    (dict(frequency_mhz=1e-300), "frequency_mhz: frequency 1e-300 MHz must be in [0.1, 100]"),
    (dict(dynamic_range_db=-3.0), "dynamic_range_db: dynamic range -3 dB must be in (0, 200]"),
    (dict(dynamic_range_db=1e300), "dynamic_range_db: dynamic range 1e+300 dB must be in (0, 200]"),
])
def test_simulation_errors_name_the_setting(kwargs, message):
    with pytest.raises(ValueError) as e:
        sonoslice.SimulationSettings(**kwargs)
    assert str(e.value).startswith(message) and "--" not in str(e.value), str(e.value)


def test_tissue_tables_are_lists_of_tissues():
    table = sonoslice.default_tissues()
    assert all(isinstance(t, sonoslice.Tissue) for t in table) and len(table) == 10
    liver = next(t for t in table if t.name == "liver")
    assert dict(liver)["label"] == liver["label"] == liver.label == 4
    assert list(dict(liver)) == ["name", "label", "impedance_mrayl", "attenuation_db_cm_mhz", "scatter_mean",
                                 "scatter_density"]
    assert eval(repr(liver), {"Tissue": sonoslice.Tissue}) == liver
    assert sonoslice.Tissue(**dict(liver)) == liver
    with pytest.raises(ValueError, match="impedance_mrayl -1 must be > 0 and <= 1000$"):
        sonoslice.Tissue(name="x", label=1, impedance_mrayl=-1.0)
    for key, value in (("impedance_mrayl", 1e300), ("attenuation_db_cm_mhz", 2000.0), ("scatter_mean", math.inf),
                       ("scatter_density", 1e7), ("scatter_density", math.nan)):
        with pytest.raises(ValueError, match="^" + re.escape(f"Tissue: tissue 'x' (label 1): {key} {value:g} must be ")):
            sonoslice.Tissue(name="x", label=1, **{key: value})
    # Dicts are read by the table files' parser: the same required keys and checks.
    with pytest.raises(ValueError, match='missing "scatter_mean"'):
        sonoslice._ext.tissue_table([dict(name="x", label=1, impedance_mrayl=1.5, attenuation_db_cm_mhz=0.5)])
    assert sonoslice._ext.tissue_table([dict(t) for t in table]) == table
    assert sonoslice._ext.tissue_table({"tissues": table}) == table


# ---- pose samplers --------------------------------------------------------------------------------
def test_sampler_settings_from_keywords_and_dicts_are_one_path():
    d = {"type": "sweep", "motion": "fan", "step": 2.0, "frames": 3, "start": np.eye(4), "jitter_deg": 0.5}
    a, b = sonoslice.SamplerSettings(**d), sonoslice.SamplerSettings.from_dict(d)
    assert (a.type, a.motion, a.step, a.frames, a.jitter_deg) == ("sweep", "fan", 2.0, 3, 0.5)
    assert np.array_equal(a.start, np.eye(4)) and a.base is None and repr(a) == repr(b)
    probe = sonoslice.Probe.workload("W1")
    seeds = [1, 2]
    np.testing.assert_array_equal(sonoslice.PoseSampler(a, probe).sample(seeds),
                                  sonoslice.PoseSampler(d, probe).sample(seeds))
    skin = sonoslice.SamplerSettings(type="skin", tilt_deg=(-10, 10), reject={"min_body": 0.5})
    assert skin.tilt_deg == (-10.0, 10.0) and skin.rotation_deg == (0.0, 360.0) and skin.reject.min_body == 0.5
    for bad, message in (({"type": "skin", "tilt": 3}, "unknown key 'tilt'"),
                         ({"type": "skin", "cone_deg": 3}, "does not apply to a skin sampler"),
                         ({"type": "skin", "threshold_hu": math.nan}, "sampler.threshold_hu: expected a finite"),
                         ({"type": "skin", "reject": {"min_body": object()}}, "sampler.reject.min_body")):
        for make in (lambda: sonoslice.SamplerSettings(**bad), lambda: sonoslice.SamplerSettings.from_dict(bad)):
            with pytest.raises(ValueError, match=message.replace(".", r"\.")):
                make()


def test_calibration_mode_reports_its_probe_side_correction(phantom, poses):
    ct, _ = phantom
    probe = sonoslice.Probe.linear(40, 30, 0.5)
    truth = np.asarray(poses[:6], float)
    frames = sonoslice.Slicer(ct, probe).slice(truth)
    X0 = np.eye(4)
    X0[:3, 3] = [0.8, -0.6, 0.5]
    initial = truth @ np.linalg.inv(X0)  # every pose off by the same probe-side X0
    refined, report = sonoslice.register(ct, probe, frames, initial, mode="calibration", pyramid=(2, 1))
    assert report["mode"] == "calibration" and np.asarray(report["correction"]).shape == (4, 4)
    np.testing.assert_allclose(np.asarray(report["correction"])[:3, 3], X0[:3, 3], atol=0.1)
    np.testing.assert_allclose(refined[:, :3, 3], truth[:, :3, 3], atol=0.1)
    # The sweep's own cost: NCC over every frame's pixels at once, near 0 on noise-free frames.
    assert 0 <= report["sweep_metric"] < 1e-3
    # The halves check (calibration's halves, each refined alone on the probe side): one
    # calibration error explains both halves.
    assert 0 <= report["halves_mm"] < 0.1


@pytest.mark.parametrize("make", [
    lambda seed: sonoslice.RegistrationSettings(seed=seed),
    lambda seed: sonoslice.SimulationSettings(seed=seed),
])
def test_seeds_outside_64_bits_are_refused_naming_the_seed(make):
    for bad in (-1, 2**64):
        with pytest.raises(ValueError, match=f"^seed {bad}: expected a whole number from 0 to 18446744073709551615"):
            make(bad)
    assert make(2**64 - 1).seed == 2**64 - 1 and make(0).seed == 0
    with pytest.raises(ValueError, match="^base_seed: expected an integer from 0 to 2"):
        sonoslice.sample_seeds(2**64, 0, 0, 1)
