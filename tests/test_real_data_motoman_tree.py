"""CTU Motoman MA1400 as a tree (issue 14): the torso joint E once, both arms on it, calibrated from self-contact
(both arms) and the right arm's laser-tracker reflector together (docs/real-data.md "CTU Motoman ... as a tree").
Reads ../shared/datasets/ctu-motoman-dual-arm; skipped when absent."""

import numpy as np
import pytest

import holdout as ho
import realdata as rd
from kincal.estimation import calibrate, evaluate
from kincal.kinematics import forward_kinematics
from kincal.kinematics.tree import tip_pose

try:
    PATH = rd.folder(rd.MOTOMAN)
except rd.DataMissing as exc:  # pragma: no cover - depends on the machine
    pytest.skip(str(exc), allow_module_level=True)

FREE = ["offsets", "left.home"]  # every joint offset of both arms and the torso, the left end effector's centre
NOISE = rd.Noise(0.1e-3, 1.0, 0.0)  # what the joint fit leaves (variance factor about 4)


def _split(ds, share=0.7):
    order = np.random.default_rng(0).permutation(ds.size)
    cut = int(share * ds.size)
    return ds.subset(order[:cut]), ds.subset(order[cut:])


def test_the_tree_is_the_two_torso_copies():
    rng = np.random.default_rng(0)
    flat, tree = rd.motoman_robot(), rd.motoman_tree()
    for side in ("right", "left"):
        q = rng.uniform(-1, 1, (20, 7))
        np.testing.assert_allclose(tip_pose(tree, side, {"torso": q[:, :1], side: q[:, 1:]}),
                                   forward_kinematics(flat[side], q), atol=1e-12)


def test_both_arms_from_self_contact_and_the_tracker_together():
    """Self-contact alone calibrates the two arms only relative to each other; the right arm's tracker data pin
    the right arm, so both arms' offsets come out. Held out: 30 % of the contacts and of the tracker poses."""
    touch, leica = rd.motoman_tree_data(PATH)
    (train, test), (ltrain, ltest) = _split(touch), _split(leica)
    res = calibrate(rd.motoman_tree(), [train, ltrain], FREE, noise=NOISE)
    assert res.status == "converged" and res.sigma2 < 10
    names = [e.name for e in res.estimates]
    assert names.count("torso.E.offset") == 1 and not any(n.startswith(("right.E", "left.E")) for n in names)
    assert any(m.startswith("torso.E.offset cannot be identified") and "tracker" in m for m in res.messages)
    both = [e for e in res.estimates if e.name.split(".")[0] in ("right", "left") and e.name.endswith("L.offset")]
    assert len(both) == 2 and all(np.isfinite(e.std) for e in both)
    # the authors (right arm offsets from self-contact): 1.02 mm on their test contacts; the same offsets on the
    # reflector: 0.173 mm RMS (docs/real-data.md)
    assert evaluate(res.robot, [test])[0].position_rms < 0.5e-3
    assert np.sqrt(np.mean(ho.prediction_errors(res, ltest)[0] ** 2)) < 0.173e-3
