"""Constraint-design studies: spec validation, the same table on a local pool and a Dask cluster, resuming
an interrupted study, and one case's metrics against a direct simulation of the same settings."""

from __future__ import annotations

import csv

import numpy as np
import pandas as pd
import pytest
from test_simulation import quintic_z

from crane_reference.analysis.study.case import run_case
from crane_reference.analysis.study.report import write_report
from crane_reference.analysis.study.runner import load_results, run_study
from crane_reference.analysis.study.spec import StudyError, parse_spec
from crane_reference.analysis.tracking.closed_loop import TrackingSpec, run_tracking
from crane_reference.model.chain import build_model
from crane_reference.model.config import load_config
from crane_reference.motion.simulation import Scenario, simulate

SPEC = {"variant": "rigid", "duration": 0.4, "step": 0.002,
        "vary": {"ellipse_a": {"values": [3.0, 3.2, 14.0]}, "payload_mass": {"values": [0.0, 300.0]}},
        "limits": {"ee_speed_m_s": 10.0}}


def deterministic(table: pd.DataFrame) -> pd.DataFrame:
    return table.drop(columns=["wall_s"])


@pytest.mark.parametrize(("change", "fragment"), [
    ({"variant": "stiff"}, "variant = 'stiff': must be one of flexible, rigid, both"),
    ({"duration": -1}, "duration = -1: must be a number in"),
    ({"vary": {"ellipse_c": {"values": [3]}}}, "vary.ellipse_c: unknown parameter; allowed: ellipse_a"),
    ({"vary": {"n_rfe": {"values": [2.5]}}}, "vary.n_rfe.values[0] = 2.5: must be an integer"),
    ({"vary": {"ellipse_a": {"low": 3.0, "high": 2.0}}, "samples": 3}, "vary.ellipse_a: low = 3 must be below high"),
    ({"vary": {"ellipse_a": {"low": 2.0, "high": 3.0}}}, "samples = 0: must be an integer in [1, 100000]"),
    ({"limits": {"speed": 1.0}}, "limits = {'speed': 1.0}: must map some of"),
    ({"colour": "red"}, "unknown field(s) colour"),
    ({"tracking": {"controller": "lqr"}}, "tracking.controller = 'lqr': must be one of pd, pid"),
    ({"tracking": {"rate": 300.0}}, "tracking.rate = 300 Hz: its period must be a whole number of steps"),
    ({"tracking": {"gain": 3}}, "tracking = {'gain': 3}: must map some of controller, feedforward"),
    ({"vary": {"feedforward": {"values": [2]}}}, "vary.feedforward.values[0] = 2: must be an integer in [0, 1]"),
])
def test_bad_specs_name_the_field(change, fragment):
    with pytest.raises(StudyError) as error:
        parse_spec({**SPEC, **change})
    assert fragment in str(error.value)


def test_random_ranges_are_seeded_and_within_bounds():
    spec = parse_spec({**SPEC, "vary": {"ellipse_a": {"low": 2.5, "high": 3.5}, "n_rfe": {"low": 2, "high": 8}},
                       "samples": 20, "seed": 3})
    cases = spec.cases()
    assert len(cases) == 20 and cases == parse_spec({**SPEC, "vary": spec_vary(spec), "samples": 20,
                                                     "seed": 3}).cases()
    assert all(2.5 <= c.values["ellipse_a"] <= 3.5 and c.values["n_rfe"] in range(2, 9) for c in cases)
    assert len({c.key for c in cases}) == 20


def spec_vary(spec):
    return {name: {"low": low, "high": high} for name, (low, high) in spec.ranges.items()}


@pytest.mark.slow
def test_local_pool_and_dask_cluster_give_the_same_table(tmp_path):
    from distributed import LocalCluster

    spec = parse_spec(SPEC)
    local = run_study(spec, tmp_path / "local", workers=2, progress=False)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        remote = run_study(spec, tmp_path / "dask", scheduler=cluster.scheduler_address, progress=False)
    assert len(local) == 6
    pd.testing.assert_frame_equal(deterministic(local), deterministic(remote), check_exact=True)
    # the unreachable ellipse is an infeasible row with its reason, not a crash
    unreachable = local[local["ellipse_a"] == 14.0]
    assert not unreachable["feasible"].any() and unreachable["reason"].str.contains("out of the crane's reach").all()
    assert local.loc[local["ellipse_a"] < 14.0, "feasible"].all()
    files = write_report(spec, local, tmp_path / "local")
    assert all(f.exists() for f in files)
    assert pd.read_parquet(files[0]).shape == local.shape
    assert "every feasible case with ellipse_a <= 3.2 stays within it" in files[-1].read_text()


def test_an_interrupted_study_resumes_without_recomputing(tmp_path):
    spec = parse_spec({**SPEC, "vary": {"ellipse_a": {"values": [3.0, 3.1, 3.2]}}})
    seen = []

    def interrupt_after_two(row):
        seen.append(row["key"])
        if len(seen) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_study(spec, tmp_path, workers=1, progress=False, on_row=interrupt_after_two)
    kept = load_results(tmp_path)
    assert list(kept["key"]) == sorted(seen, key=lambda key: [c.key for c in spec.cases()].index(key))
    resumed = []
    table = run_study(spec, tmp_path, workers=1, progress=False, on_row=lambda row: resumed.append(row["key"]))
    assert len(resumed) == 1 and resumed[0] not in seen  # only the missing case was computed
    assert list(table["case"]) == [0, 1, 2] and table.attrs["reused"] == 2
    with (tmp_path / "results.csv").open() as handle:  # the file itself in case order, as the table
        assert [row["case"] for row in csv.DictReader(handle)] == ["0", "1", "2"]
    assert not [c for c in table.columns if c.startswith(("track_", "diff_", "tip_", "vibration_"))]  # rigid, alone
    fresh = run_study(spec, tmp_path / "fresh", workers=1, progress=False)
    pd.testing.assert_frame_equal(deterministic(table), deterministic(fresh), check_exact=True)


def test_case_metrics_against_a_direct_simulation():
    """The study's case (a larger ellipse and a payload) against the same settings simulated here, with
    the metrics computed independently: |v_E| from differences of E's positions, the force at E from the
    Lagrange multipliers and the constraint gradients."""
    spec = parse_spec({**SPEC, "duration": 0.6, "step": 0.001,
                       "vary": {"ellipse_a": {"values": [3.2]}, "payload_mass": {"values": [300.0]}}})
    (case,) = spec.cases()
    row = run_case(spec, case)
    params = load_config()
    params = type(params)(**{**params.__dict__, "payload": 300.0,
                             "task": type(params.task)(3.2, params.task.ellipse_b, params.task.z_increment,
                                                       params.task.rise_time)})
    scenario = Scenario(params, "rigid")
    assert scenario.model.bodies[-1].inertia.mass == 300.0 and build_model(params, "rigid").dof == 9
    trajectory = simulate(scenario.motion, scenario.equilibrium.q, 0.6, step=0.001)
    speed = np.linalg.norm(np.diff(trajectory.ee_position, axis=0), axis=1) / np.diff(trajectory.t)
    assert row["ee_speed_m_s"] == pytest.approx(speed.max(), rel=2e-3)
    forces = [sum(lam * gradient for lam, gradient in zip(
        reactions, scenario.motion.constraints.position_jacobian(t, p), strict=True))
        for t, p, reactions in zip(trajectory.t, trajectory.ee_position, trajectory.reactions, strict=True)]
    assert row["constraint_force_n"] == pytest.approx(np.linalg.norm(forces, axis=1).max(), rel=1e-9)
    assert row["kdc_min_singular_value"] == trajectory.kdc_min_singular_value.min()
    assert row["residual_m"] == trajectory.residual_distance.max() and row["feasible"]


@pytest.mark.slow
def test_tracking_columns_of_a_case_against_the_closed_loop_run_here():
    """A study that varies the feedforward switches the closed loop on; its height error column is the
    largest |z_E - z_a(t)| of the plant's E, with eq. (5.2) written out here, and the rigid feedforward
    holds the payload where the PD alone lets it sag."""
    spec = parse_spec({"variant": "rigid", "duration": 0.5, "step": 0.001,
                       "vary": {"feedforward": {"values": [0, 1]}}, "tracking": {"bandwidth": 1.5}})
    rows = {int(case.values["feedforward"]): run_case(spec, case) for case in spec.cases()}
    params = load_config()
    scenario = Scenario(params, "rigid")
    for switch, feedforward in ((0, "none"), (1, "rigid")):
        run = run_tracking(params, TrackingSpec(variant="rigid", bandwidth=1.5, feedforward=feedforward,
                                                duration=0.5))
        z_a = quintic_z(run.t, scenario.z_static, params.task.z_increment, params.task.rise_time)
        assert rows[switch]["track_height_error_max_m"] == pytest.approx(
            np.abs(run.plant.ee_position[:, 2] - z_a).max(), rel=1e-9, abs=1e-12)
        assert rows[switch]["feasible"]
    assert rows[1]["track_height_error_max_m"] < 0.2 * rows[0]["track_height_error_max_m"]
