"""Design of experiments (issue #11, items 4-5): selection against brute force, candidates reachable and within
limits, designed better than random where it matters, the CLI and its outputs, and bad input."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from kincal import robots
from kincal.analysis import design_pool
from kincal.analysis.design import (CRITERIA, D_GAIN, MAX_PASSES, POOLED_ROWS, _LogDet, criterion_value, information,
                                    select)
from kincal.errors import KincalError, ModelError
from kincal.estimation import Noise, calibrate
from kincal.kinematics import forward_kinematics
from kincal.simulate import generate_markers, perturb_robot
from kincal.workflow.design import Candidates, candidate_pool, choose, design

UR10 = robots.load("ur10")
ARM = next(iter(UR10.arms))
FRIDA = robots.load("frida")


def _pool(seed=0, N=12, k=2, r=4):
    return np.random.default_rng(seed).normal(size=(N, k, r))


@pytest.mark.parametrize("criterion", CRITERIA)
def test_selection_against_brute_force(criterion):
    """On a pool of 12 (495 subsets of 4) the selection comes within 5 % of the best subset's criterion and
    beats 99 % of all subsets, for every criterion and 6 pools; on most it is the best subset."""
    W = np.random.default_rng(9).normal(size=(7, 3, 4))
    hits = 0
    for seed in range(6):
        X = _pool(seed)
        values = np.array([criterion_value(information(X[list(c)]) + 1e-12 * np.eye(4), criterion, W, 4)
                           for c in itertools.combinations(range(len(X)), 4)])
        got = select(X, 4, criterion, workspace=W).value
        best = values.max()
        assert got >= best - 0.05 * abs(best) - 1e-12, (criterion, seed, got, best)
        assert np.mean(values <= got + 1e-12) >= 0.99
        hits += got >= best - 1e-9 * abs(best)
    assert hits >= 5


def test_rank_k_bookkeeping_matches_direct_computation():
    X = _pool(1, N=30, k=3, r=5)
    M = np.eye(5) + information(X[:6])
    st = _LogDet(X, M.copy())
    st.add(10)
    st.add(3, -1.0)
    M2 = M + X[10].T @ X[10] - X[3].T @ X[3]
    assert st.logdet == pytest.approx(np.linalg.slogdet(M2)[1])
    G = np.einsum("nkr,rs,nls->nkl", X, np.linalg.inv(M2), X)
    np.testing.assert_allclose(st.gram(st.Minv), G, atol=1e-10)
    Binv, ld = st.removed(4)
    G_wo = st.gram(Binv)
    M3 = M2 - X[4].T @ X[4]
    assert ld == pytest.approx(np.linalg.slogdet(M3)[1])
    np.testing.assert_allclose(G_wo, np.einsum("nkr,rs,nls->nkl", X, np.linalg.inv(M3), X), atol=1e-9)


def test_deterministic_for_a_seed():
    X = _pool(2, N=200, k=3, r=6)
    a, b = select(X, 8, "E", seed=4), select(X, 8, "E", seed=4)
    np.testing.assert_array_equal(a.indices, b.indices)


def test_candidates_are_reachable_and_within_limits():
    """Every kind's pool comes from its generator on the nominal robot: within the limits and satisfying the
    experiment's constraint (a clamp closes: the tool at the fixture)."""
    for kind, robot, options in (("markers", UR10, {"arm": ARM, "markers": 1}),
                                 ("clamp", FRIDA, {"arm": "right"}),
                                 ("dual", FRIDA, {"known_clamp": True})):
        ds = candidate_pool(robot, kind, options, 40, 0)
        for arm in ds.arms:
            assert robot[arm].within_limits(ds.q[arm]).all()
        d = choose(robot, ds, 30 if kind != "markers" else 20, free="offsets" if kind != "markers" else "kinematic",
                   noise=Noise(position=5e-5, joint=1e-5))
        for arm in ds.arms:  # chosen rows are pool rows
            assert all(any(np.array_equal(r, p) for p in ds.q[arm]) for r in d.dataset.q[arm])
    clamp = candidate_pool(FRIDA, "clamp", {"arm": "right"}, 30, 1)
    T = forward_kinematics(FRIDA["right"], clamp.q["right"])
    assert np.ptp(T[:, :3, 3], axis=0).max() < 1e-6  # one clamp: the tool never moves


def test_workspace_box_and_line_of_sight():
    lo, hi = np.array([-2.0, -2.0, 0.3]), np.array([2.0, 2.0, 2.0])
    ds = candidate_pool(UR10, "markers", {"arm": ARM, "markers": 1}, 400,
                        0, Candidates(box=(lo, hi), cone=np.radians(60)))
    T = forward_kinematics(UR10[ARM], ds.q[ARM])
    assert 0 < ds.size < 400 and np.all(T[:, 2, 3] >= 0.3)
    with pytest.raises(KincalError, match="widen the box"):
        candidate_pool(UR10, "markers", {"arm": ARM}, 50, 0, Candidates(box=(lo + 10, hi + 10)))
    with pytest.raises(ModelError, match="tracker experiments"):
        candidate_pool(FRIDA, "clamp", {"arm": "right"}, 10, 0, Candidates(cone=0.5))


def test_designed_beats_random_after_calibration():
    """The measure that counts: calibrate from K designed or K random configurations of the same pool (measured
    on a perturbed robot) and validate on fresh ones. Over 4 seeds D-optimal halves the spread and lowers the
    mean validation error at K = 18."""
    errs = {"random": [], "D": []}
    for s in range(4):
        true = perturb_robot(UR10, "fine", rng=100 + s)
        pool, _, val = generate_markers(true, ARM, n=1500, rng=s, noise=Noise(position=5e-5), markers=1)
        rng = np.random.default_rng(1000 + s)
        picks = {"random": pool.subset(rng.choice(pool.size, 18, replace=False)),
                 "D": choose(UR10, pool, 18, free="kinematic", noise=Noise(position=5e-5), seed=s).dataset}
        for name, ds in picks.items():
            res = calibrate(UR10, [ds], "kinematic", noise=Noise(position=5e-5), validation=[val[ARM]])
            errs[name].append(res.validation[0].after.position_rms)
    assert np.mean(errs["D"]) < 0.9 * np.mean(errs["random"]), errs


def test_design_reports_and_predicts():
    d = design(UR10, "markers", {"arm": ARM, "markers": 1}, 20, free="kinematic", pool=600,
               noise=Noise(position=5e-5), criterion="I")
    assert d.rank == 27 and len(d.dataset.q[ARM]) == 20
    assert d.tool_rms < d.random_tool_rms  # I targets the predicted tool error over the workspace
    assert d.selection.value >= d.random


def test_bad_input_says_what_to_change():
    with pytest.raises(ModelError, match=r"choose at least 10 configurations \(18 to check the fit\)"):
        design(UR10, "markers", {"arm": ARM, "markers": 1}, 9, free="kinematic", pool=100,
               noise=Noise(position=5e-5))
    with pytest.raises(ModelError, match="enlarge the pool"):
        design(UR10, "markers", {"arm": ARM, "markers": 1}, 30, free="kinematic", pool=25,
               noise=Noise(position=5e-5))
    with pytest.raises(ModelError, match="at least 1 candidate"):
        design(UR10, "markers", {"arm": ARM}, 30, pool=0)
    with pytest.raises(ModelError, match="criterion"):
        select(_pool(), 3, "Z")


def test_next_makes_identifiable_what_more_data_can_and_names_what_it_cannot():
    """--next on a tracker data set of one configuration: the chosen ones make every reachable parameter
    identifiable; the tracker gauge (joint 1) and the marker gauge (the last joint) stay, named as structural.
    One clamp of unknown pose: j1 and j7 can never be identified from more clamp data, and that is said."""
    from kincal.workflow.augment import next_configurations
    ds, _, _ = generate_markers(UR10, ARM, n=40, rng=0, noise=Noise(position=5e-5), markers=3)
    a = next_configurations(UR10, [ds.subset(np.arange(1))], 4, free="offsets", noise=Noise(position=5e-5),
                            pool=300)
    assert a.rank_before < a.rank_after == 19 and "arm.elbow.offset" in a.gained
    assert set(a.gained) == set(a.reachable)
    assert {n for n, _ in a.structural} == {"arm.shoulder_pan.offset", "arm.wrist_3.offset"}
    from kincal.simulate import generate_clamp
    clamp, _, _ = generate_clamp(FRIDA, "right", n=30, rng=0, noise=Noise(joint=1e-5))
    b = next_configurations(FRIDA, [clamp], 5, free="offsets", noise=Noise(joint=1e-5), pool=60)
    assert b.rank_before == b.rank_after == 11 and not b.gained
    assert {n for n, _ in b.structural} == {"right.j1.offset", "right.j7.offset"}
    assert all("fixture" in words for _, words in b.structural)


def test_cli_design_writes_targets_in_model_and_controller_order(tmp_path, capsys):
    from kincal.cli import main
    out = tmp_path / "design"
    assert main(["design", "frida_dual_bracket", "-n", "30", "--pool", "200", "-o", str(out)]) == 0
    assert "chose 30 of 200" in capsys.readouterr().out
    targets = np.loadtxt(out / "targets.csv", delimiter=",", skiprows=1)
    motor = np.loadtxt(out / "controller.csv", delimiter=",", skiprows=1)
    header = (out / "targets.csv").read_text().splitlines()[0].split(",")
    assert targets.shape == (30, 14) and header[0] == "left.j1" and header[-1] == "right.j7"
    left = FRIDA["left"]
    order = np.asarray(left.controller_order)
    np.testing.assert_allclose(motor[:, :7], targets[:, :7][:, order] * left.gear_ratios[order])
    for i, arm in enumerate(("left", "right")):
        assert FRIDA[arm].within_limits(targets[:, 7 * i: 7 * i + 7]).all()
    summary = (out / "design.yaml").read_text()
    assert "criterion_random_median" in summary and "format: kincal-design" in summary
    assert main(["design", "frida_dual_bracket", "-n", "30", "--pool", "200", "-o", str(out)]) == 2  # no overwrite
    assert "not overwritten" in capsys.readouterr().err
    assert not list(tmp_path.glob(".design.kincal-tmp-*"))


def test_cli_design_next_and_bad_input(tmp_path, capsys):
    from kincal.cli import main
    assert main(["simulate", "frida_clamp_one", "-o", str(tmp_path / "sim"), "--quiet"]) == 0
    job = tmp_path / "job.yaml"
    job.write_text("format: kincal-job\nversion: 1\nmodel: frida\ndata: [sim/data.yaml]\nfree: offsets\n")
    capsys.readouterr()
    assert main(["design", str(job), "--next", "3", "--pool", "40", "-o", str(tmp_path / "next")]) == 0
    out = capsys.readouterr().out
    assert "calibrating the job first" in out
    assert "cannot become identifiable with more" in out and "right.j1.offset cannot be identified" in out
    assert (tmp_path / "next" / "targets.csv").read_text().count("\n") == 4
    for args, words in ((["frida_dual_bracket", "-o", str(tmp_path / "x")], "either -n K"),
                        (["ur10_tracker_markers", "-n", "30", "--box", "1,2,3", "-o", str(tmp_path / "y")], "6 comma"),
                        (["frida_dual_bracket", "-n", "2", "--pool", "50", "-o", str(tmp_path / "z")], "choose at least")):
        assert main(["design", *args]) == 2
        err = capsys.readouterr().err
        assert words in err and err.count("\n") == 1


def test_cli_design_from_a_job_without_measured_data(tmp_path, capsys):
    """`kincal design JOB -n K`: a job naming a scenario draws the scenario's candidates; a job naming a
    configurations file chooses among its configurations (every chosen row is one of them)."""
    from kincal.cli import main
    job = tmp_path / "scenario.yaml"
    job.write_text("model: frida\nfree: offsets\ndata:\n  - scenario: frida_dual_bracket\n    noise: {joint_deg: 0.001}\n")
    assert main(["design", str(job), "-n", "20", "--pool", "150", "-o", str(tmp_path / "a")]) == 0
    assert "chose 20 of 150" in capsys.readouterr().out
    targets = np.loadtxt(tmp_path / "a" / "targets.csv", delimiter=",", skiprows=1)
    assert targets.shape == (20, 14)
    pool = np.random.default_rng(3).uniform(-2, 2, size=(200, 6))
    header = ",".join(f"{ARM}.{j}" for j in UR10[ARM].joint_names)
    np.savetxt(tmp_path / "cell.csv", pool, delimiter=",", header=header, comments="")
    job = tmp_path / "configs.yaml"
    job.write_text("model: ur10\nfree: kinematic\ndata:\n  - configurations: cell.csv\n    experiment: {kind: markers, "
                   f"arm: {ARM}, markers: 3}}\n    noise: {{position_mm: 0.05}}\n")
    assert main(["design", str(job), "-n", "25", "-o", str(tmp_path / "b")]) == 0
    out = capsys.readouterr().out
    assert "choosing from the 200 configurations of data set 'cell'" in out and "chose 25 of 200" in out
    chosen = np.loadtxt(tmp_path / "b" / "targets.csv", delimiter=",", skiprows=1)
    assert all(np.abs(pool - row).max(axis=1).min() < 1e-12 for row in chosen)
    assert main(["design", str(job), "-n", "25", "--box", "0,0,0,1,1,1", "-o", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err
    assert "this job's data set gives the candidates" in err and err.count("\n") == 1


# --------------------------------------------------------- the D selection's two methods (analysis.design_pool)

@pytest.mark.parametrize("k", [1, 3, 4, 6])
def test_d_selection_against_brute_force_by_either_method(k):
    """D for candidates of few rows (k <= 3: the whole pool scored at once, ``design_pool``) and of more rows
    (k > 3: branch and bound): on pools of 12 (495 subsets of 4) within 1 % of the best subset's log det and
    better than 99 % of the subsets; on most pools the best subset."""
    hits = 0
    for seed in range(5):
        X = _pool(seed, N=12, k=k, r=6)
        values = np.array([criterion_value(information(X[list(c)]) + 1e-12 * np.eye(6), "D")
                           for c in itertools.combinations(range(len(X)), 4)])
        got, best = select(X, 4, "D").value, values.max()
        assert got >= best - 0.01 * abs(best), (k, seed, got, best)
        assert np.mean(values <= got + 1e-9) >= 0.99
        hits += got >= best - 1e-9 * abs(best)
    assert hits >= 4, (k, hits)


@pytest.mark.parametrize("k, N, shortlist", [(3, 400, 20_000), (3, 1500, 200), (4, 1500, 0)])
def test_d_exchange_ends_where_no_single_swap_pays(k, N, shortlist):
    """Whichever method and whether the passes ran on a shortlist first: no swap of one chosen configuration for
    any candidate of the whole pool raises log det by more than the exchange's threshold."""
    X = _pool(7, N=N, k=k, r=9) * np.random.default_rng(8).uniform(0.2, 2.0, size=(N, 1, 1))
    K = 8
    if k <= POOLED_ROWS:
        M0 = 1e-10 * np.eye(9)
        pool = design_pool.Pool(X, M0)
        chosen, _ = design_pool.exchange(pool, design_pool.greedy(pool, K, M0), M0, passes=MAX_PASSES,
                                         min_gain=D_GAIN, shortlist=shortlist)
    else:
        chosen = list(select(X, K, "D").indices)
    M = information(X[chosen]) + 1e-10 * np.eye(9)
    value = np.linalg.slogdet(M)[1]
    for pos, out in enumerate(chosen):
        B = M - X[out].T @ X[out]
        gains = np.linalg.slogdet(B[None] + np.einsum("nkr,nks->nrs", X, X))[1]
        gains[chosen] = -np.inf
        assert gains.max() <= value + D_GAIN + 1e-9, (pos, gains.max() - value)


def test_pooled_bookkeeping_matches_direct_computation():
    """design_pool.Pool: every candidate's X_j M^-1 X_j^T, M^-1 and log det after adding and removing
    candidates, in double precision to round-off, with single-precision updates within 1e-5; the gains are the
    log det rises."""
    X = _pool(3, N=200, k=3, r=7)
    M = np.eye(7) + information(X[:9])
    for single, tol in ((False, 1e-10), (True, 1e-5)):
        pool = design_pool.Pool(X, M.copy(), single=single)
        pool.commit(20, 1.0)
        pool.commit(4, -1.0)
        M2 = M + X[20].T @ X[20] - X[4].T @ X[4]
        assert pool.logdet == pytest.approx(np.linalg.slogdet(M2)[1], abs=tol)
        G = np.einsum("nkr,rs,nls->kln", X, np.linalg.inv(M2), X)
        np.testing.assert_allclose(pool.G, G, atol=tol)
        rise = np.linalg.slogdet(M2[None] + np.einsum("nkr,nks->nrs", X, X))[1] - np.linalg.slogdet(M2)[1]
        np.testing.assert_allclose(pool.gains(), rise, atol=tol)
        G_wo, Binv, ld = pool.moved(5, -1.0)
        M3 = M2 - X[5].T @ X[5]
        assert ld == pytest.approx(np.linalg.slogdet(M3)[1], abs=tol)
        np.testing.assert_allclose(Binv, np.linalg.inv(M3), atol=tol)
        np.testing.assert_allclose(G_wo, np.einsum("nkr,rs,nls->kln", X, np.linalg.inv(M3), X), atol=tol)


@pytest.mark.parametrize("k", [1, 2, 3, 4, 6])
def test_pooled_log_det_of_identity_plus_gram(k):
    """Closed forms (k <= 3) and the elementwise Cholesky (k > 3) against LAPACK; a candidate whose matrix is
    not positive definite scores far below any other."""
    A = np.random.default_rng(k).normal(size=(40, k, k + 1))
    G = A @ np.swapaxes(A, 1, 2)
    G[5] = -3 * np.eye(k)
    got = design_pool.logdet_eye_plus(np.ascontiguousarray(np.moveaxis(G, 0, -1)))
    ref = np.linalg.slogdet(np.eye(k) + G)[1]
    np.testing.assert_allclose(np.delete(got, 5), np.delete(ref, 5), atol=1e-12)
    if k % 2:  # an odd number of negative pivots: a negative determinant (closed forms) or a failed pivot
        assert got[5] < -600


def test_design_never_returns_a_configuration_outside_the_limits(tmp_path, capsys):
    """A pool given as data (a configurations file, measured data) may hold configurations outside the joint
    limits: they are left out, and said; a pool with none inside gets a one-line error."""
    from kincal.cli import main
    rng = np.random.default_rng(5)
    lo, hi = UR10[ARM].lower, UR10[ARM].upper
    inside = rng.uniform(np.maximum(lo, -3), np.minimum(hi, 3), size=(120, 6))
    outside = inside[:60].copy()
    outside[:, 1] = hi[1] + 0.5  # beyond the shoulder's upper limit
    pool = np.vstack([outside[:30], inside, outside[30:]])
    header = ",".join(f"{ARM}.{j}" for j in UR10[ARM].joint_names)
    np.savetxt(tmp_path / "cell.csv", pool, delimiter=",", header=header, comments="")
    np.savetxt(tmp_path / "far.csv", outside, delimiter=",", header=header, comments="")
    for name in ("cell", "far"):
        (tmp_path / f"{name}.yaml").write_text(
            f"model: ur10\nfree: kinematic\ndata:\n  - configurations: {name}.csv\n    experiment: {{kind: markers, "
            f"arm: {ARM}, markers: 1}}\n    noise: {{position_mm: 0.05}}\n")
    for criterion in ("D", "A"):
        assert main(["design", str(tmp_path / "cell.yaml"), "-n", "25", "--criterion", criterion,
                     "-o", str(tmp_path / criterion)]) == 0
        assert "left out 60 configurations outside the joint limits" in capsys.readouterr().out
        chosen = np.loadtxt(tmp_path / criterion / "targets.csv", delimiter=",", skiprows=1)
        assert UR10[ARM].within_limits(chosen).all()
        assert all(np.abs(inside - row).max(axis=1).min() < 1e-12 for row in chosen)
    assert main(["design", str(tmp_path / "far.yaml"), "-n", "25", "-o", str(tmp_path / "far")]) == 2
    err = capsys.readouterr().err
    assert "none of the 60 configurations of data set 'far' lies within the joint limits" in err
    assert err.count("\n") == 1


def test_cli_bad_pools_one_line(tmp_path, capsys):
    """From the command line: a workspace box no candidate reaches, and a configurations file without rows."""
    from kincal.cli import main
    assert main(["design", "ur10_tracker_markers", "-n", "30", "--pool", "200", "--box", "10,10,10,11,11,11",
                 "-o", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err
    assert "widen the box" in err and err.count("\n") == 1
    (tmp_path / "empty.csv").write_text(",".join(f"{ARM}.{j}" for j in UR10[ARM].joint_names) + "\n")
    (tmp_path / "job.yaml").write_text("model: ur10\nfree: kinematic\ndata:\n  - configurations: empty.csv\n"
                                       f"    experiment: {{kind: markers, arm: {ARM}}}\n")
    assert main(["design", str(tmp_path / "job.yaml"), "-n", "10", "-o", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err
    assert "no data rows" in err and err.count("\n") == 1


def test_pooled_starts_keep_the_best_exchanged_design():
    """design_pool.d_optimal with more starts (stochastic greedies, each exchanged): never a lower log det than
    the first start alone, the same greedy choice, and deterministic for a seed."""
    X = _pool(11, N=600, k=3, r=9)
    M0 = 1e-10 * np.eye(9)
    ld = lambda idx: np.linalg.slogdet(M0 + information(X[idx]))[1]  # noqa: E731
    runs = {s: design_pool.d_optimal(X, 6, M0, np.random.default_rng(2), starts=s, passes=MAX_PASSES,
                                     min_gain=D_GAIN, shortlist=20_000) for s in (1, 4)}
    assert runs[1][0] == runs[4][0] and ld(runs[4][1]) >= ld(runs[1][1]) - 1e-9
    again = design_pool.d_optimal(X, 6, M0, np.random.default_rng(2), starts=4, passes=MAX_PASSES, min_gain=D_GAIN,
                                  shortlist=20_000)
    assert again[1] == runs[4][1]
