"""The per-grasp likelihood p(grasp | y, wrist pose) and the belief it gives."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from activetouch.errors import ConfigError, DataError
from activetouch.interfaces import Grasp, Pose
from activetouch.recognition.dataset import load_npz_bytes, npz_bytes
from activetouch.recognition.grasp_likelihood import (
    GraspLikelihood,
    LikelihoodParams,
    finger_censor,
    pose_weights,
    sensor_mask,
    softmax_belief,
)

IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])
FULL = [0, 1, 2, 3, 4, 5, 6, 7]  # 8 sensors: exp(-8) against nothing felt (sensor scale 1)


def grasp(ids: list[int], angles: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> Grasp:
    n = len(ids)
    return Grasp(np.array(ids), np.zeros((n, 3)), np.full(n, 30.0), np.array(angles))


def pose_at(x: float) -> np.ndarray:
    return np.array([x, 0.0, 0.2, *IDENTITY])


def two_classes() -> GraspLikelihood:
    # Both classes grasped at x = 0 and x = 0.3: alike at 0.3, different at 0.
    return GraspLikelihood.fit(
        [
            (np.stack([pose_at(0.0), pose_at(0.3)]), [grasp(FULL), grasp([5, 6, 7])]),
            (np.stack([pose_at(0.0), pose_at(0.3)]), [grasp([]), grasp([5, 6, 7])]),
        ]
    )


def test_sensor_mask_sets_one_bit_per_sensor() -> None:
    assert sensor_mask(np.array([0, 3, 37])).tolist() == [1 + 8 + 2**37]
    assert sensor_mask(np.array([], dtype=np.int64)).tolist() == [0]
    with pytest.raises(DataError):
        sensor_mask(np.array([64]))


def test_masks_past_64_sensors_take_more_words_and_count_every_bit() -> None:
    """The BarrettHand's 96 cells: the likelihood of a grasp is that of its Hamming distance
    to each training grasp, counted here from the id sets themselves."""
    m = sensor_mask(np.array([1, 63, 64, 95]), words=2)
    assert m.tolist() == [2 + 2**63, 1 + 2**31]
    with pytest.raises(DataError):
        sensor_mask(np.array([128]), words=2)
    rng = np.random.default_rng(3)
    train = [sorted(rng.choice(96, size=int(rng.integers(0, 12)), replace=False)) for _ in range(6)]
    lik = GraspLikelihood.fit(
        [
            (np.stack([pose_at(0.0)] * 3), [grasp(t) for t in train[:3]]),
            (np.stack([pose_at(0.0)] * 3), [grasp(t) for t in train[3:]]),
        ]
    )
    assert lik.words == 2
    p = LikelihoodParams(sensor_scale=2.0, floor=1e-9)
    felt = [2, 70, 71, 90]
    got = lik.log_likelihood(grasp(felt), Pose(pose_at(0.0)[:3], IDENTITY), p)
    ham = [len(set(t) ^ set(felt)) for t in train]  # closure is equal: only the bits differ
    want = [np.log(np.mean(np.exp(-np.array(ham[k : k + 3]) / 2.0)) + 1e-9) for k in (0, 3)]
    np.testing.assert_allclose(got, want, rtol=1e-9)
    # Ignoring cells leaves them out on both sides.
    ignore = np.array([70, 90])
    got = lik.log_likelihood(grasp(felt), Pose(pose_at(0.0)[:3], IDENTITY), p, ignore)
    ham = [len((set(t) ^ set(felt)) - {70, 90}) for t in train]
    want = [np.log(np.mean(np.exp(-np.array(ham[k : k + 3]) / 2.0)) + 1e-9) for k in (0, 3)]
    np.testing.assert_allclose(got, want, rtol=1e-9)


def test_pose_weights_fall_with_distance_and_angle() -> None:
    turned = np.array([0.0, 0.0, 0.2, 0.0, 0.0, np.sin(0.1), np.cos(0.1)])  # 0.2 rad about z
    w = pose_weights(np.stack([pose_at(0.0), pose_at(0.02), turned]), pose_at(0.0), 0.02, 0.2)
    assert w[0] == pytest.approx(1.0)
    assert w[1] == pytest.approx(np.exp(-0.5))
    assert w[2] == pytest.approx(np.exp(-0.5))
    # q and -q are the same rotation
    flipped = pose_at(0.0)
    flipped[3:] = -flipped[3:]
    assert pose_weights(flipped[None], pose_at(0.0), 0.02, 0.2)[0] == pytest.approx(1.0)


def test_a_grasp_is_evidence_for_the_class_that_felt_it_there() -> None:
    lik = two_classes()
    p = LikelihoodParams()
    at0 = Pose(pose_at(0.0)[:3], IDENTITY)
    ll = lik.log_likelihood(grasp(FULL), at0, p)
    assert ll[0] > ll[1] + 3.5
    # An empty grasp says something too: class 1 felt nothing there.
    ll_empty = lik.log_likelihood(grasp([]), at0, p)
    assert ll_empty[1] > ll_empty[0] + 3.5
    # Where both classes feel the same, the grasp cannot tell them apart.
    at3 = Pose(pose_at(0.3)[:3], IDENTITY)
    same = lik.log_likelihood(grasp([5, 6, 7]), at3, p)
    assert same[0] == pytest.approx(same[1])


def test_finger_closure_tells_a_wide_object_from_a_narrow_one() -> None:
    lik = GraspLikelihood.fit(
        [
            (pose_at(0.0)[None], [grasp([1, 2, 3], (0.8, 0.8, 0.8))]),
            (pose_at(0.0)[None], [grasp([1, 2, 3], (1.2, 1.2, 1.2))]),
        ]
    )
    # The kernel's verdict, under a floor low enough not to cap it (the default caps a grasp's
    # say at log(1 / floor) nats)
    ll = lik.log_likelihood(
        grasp([1, 2, 3], (1.15, 1.2, 1.2)),
        Pose(pose_at(0.0)[:3], IDENTITY),
        LikelihoodParams(floor=1e-4),
    )
    assert ll[1] > ll[0] + 5.0


def test_a_class_without_grasps_near_the_pose_has_no_say() -> None:
    lik = GraspLikelihood.fit(
        [
            (pose_at(0.0)[None], [grasp([1])]),
            (pose_at(0.0)[None], [grasp([2])]),
            (pose_at(0.5)[None], [grasp([1])]),  # far away: nothing near x = 0
        ]
    )
    ll = lik.log_likelihood(grasp([1]), Pose(pose_at(0.0)[:3], IDENTITY), LikelihoodParams())
    assert ll[0] > ll[1]
    assert np.exp(ll[2]) == pytest.approx((np.exp(ll[0]) + np.exp(ll[1])) / 2)


def test_belief_sums_evidence_over_grasps() -> None:
    lik = two_classes()
    p = LikelihoodParams()
    at0 = Pose(pose_at(0.0)[:3], IDENTITY)
    log_b = np.zeros(2)
    for _ in range(2):
        log_b += lik.log_likelihood(grasp(FULL), at0, p)
    b = softmax_belief(log_b)
    assert b.sum() == pytest.approx(1.0)
    assert b[0] > 0.999
    assert softmax_belief(np.array([1000.0, 0.0]))[0] == pytest.approx(1.0)  # no overflow


def test_arrays_round_trip_and_bad_arrays_are_refused() -> None:
    lik = two_classes()
    # through the .npz bytes a model file holds
    back = GraspLikelihood.from_arrays(load_npz_bytes(npz_bytes(lik.to_arrays()), Path("x")))
    for name in ("poses", "labels", "masks", "closure"):
        np.testing.assert_array_equal(getattr(back, name), getattr(lik, name))
    assert back.n_classes == 2
    bad = lik.to_arrays()
    bad["closure"] = bad["closure"][:1]
    with pytest.raises(DataError):
        GraspLikelihood.from_arrays(bad)
    bad = lik.to_arrays()
    del bad["masks"]
    with pytest.raises(DataError):
        GraspLikelihood.from_arrays(bad)


def test_kernel_widths_must_be_positive() -> None:
    with pytest.raises(ConfigError, match="likelihood_pose_sigma_m"):
        LikelihoodParams(pose_sigma_m=0.0)


def test_many_poses_at_once_give_what_each_pose_alone_gives() -> None:
    # The pose belief asks for one grasp at every placement hypothesis in one call.
    rng = np.random.default_rng(3)
    per_class = []
    for _ in range(3):
        poses = np.concatenate([rng.uniform(-0.1, 0.1, (40, 3)), rng.normal(size=(40, 4))], axis=1)
        gs = [grasp(sorted(rng.choice(38, 3, replace=False).tolist())) for _ in range(40)]
        per_class.append((poses, gs))
    lik = GraspLikelihood.fit(per_class)
    params = LikelihoodParams()
    g = grasp([1, 5, 30], (0.8, 1.1, 0.9))
    xs = np.concatenate([rng.uniform(-0.05, 0.05, (25, 3)), rng.normal(size=(25, 4))], axis=1)
    xs[-1, :3] = [5.0, 5.0, 5.0]  # nowhere near any training grasp: no evidence
    ignore = np.array([5])
    many = lik.log_likelihood_at_poses(g, xs, params, ignore)
    one = np.stack([lik.log_likelihood(g, Pose(x[:3], x[3:]), params, ignore) for x in xs])
    assert many == pytest.approx(one, abs=1e-12)
    assert np.all(many[-1] == np.log(1.0 + params.floor))


def test_each_class_at_its_own_poses_gives_what_those_poses_alone_give() -> None:
    # Classes that turn about different points stand elsewhere under one hypothesis: class y
    # is read at poses[class_groups[y]], as if asked with those poses alone. Every class has
    # a grasp at every training pose (the shared grid), so each has a say near them.
    rng = np.random.default_rng(5)
    poses = np.concatenate([rng.uniform(-0.1, 0.1, (40, 3)), rng.normal(size=(40, 4))], axis=1)
    per_class = []
    for _ in range(3):
        gs = [grasp(sorted(rng.choice(38, 3, replace=False).tolist())) for _ in range(40)]
        per_class.append((poses, gs))
    lik = GraspLikelihood.fit(per_class)
    params = LikelihoodParams()
    g = grasp([2, 7, 31], (0.9, 1.0, 1.2))
    xs = poses[rng.choice(40, (2, 12))].copy()
    xs[..., :3] += rng.normal(0.0, 0.003, (2, 12, 3))
    xs[1, -1, :3] = [5.0, 5.0, 5.0]  # nowhere near any training grasp
    groups = np.array([1, 0, 1])
    both = lik.log_likelihood_at_poses(g, xs, params, class_groups=groups)
    for y, grp in enumerate(groups):
        alone = lik.log_likelihood_at_poses(g, xs[grp], params)
        assert both[:-1, y] == pytest.approx(alone[:-1, y], abs=1e-12)
    # At the last hypothesis classes 0 and 2 stand nowhere near a training grasp: no say,
    # they get what class 1 (standing elsewhere, near its grasps) has there.
    assert both[-1, 1] == pytest.approx(lik.log_likelihood_at_poses(g, xs[0], params)[-1, 1])
    assert both[-1, [0, 2]] == pytest.approx([both[-1, 1]] * 2, abs=1e-12)


def test_training_grasps_in_any_class_order_give_the_same_likelihood() -> None:
    # Per-class sums run over the classes' stretches of grasps; arrays stored in another order
    # (the classes interleaved) must give the same p(grasp | y, pose).
    rng = np.random.default_rng(4)
    per_class = []
    for _ in range(3):
        poses = np.concatenate([rng.uniform(-0.05, 0.05, (30, 3)), rng.normal(size=(30, 4))], 1)
        gs = [grasp(sorted(rng.choice(38, 3, replace=False).tolist())) for _ in range(30)]
        per_class.append((poses, gs))
    lik = GraspLikelihood.fit(per_class)
    order = rng.permutation(len(lik.labels))
    mixed = GraspLikelihood(
        lik.poses[order], lik.labels[order], lik.masks[order], lik.closure[order], 3
    )
    g = grasp([2, 7, 20], (0.9, 1.0, 1.2))
    xs = np.concatenate([rng.uniform(-0.03, 0.03, (10, 3)), rng.normal(size=(10, 4))], axis=1)
    params = LikelihoodParams()
    want = lik.log_likelihood_at_poses(g, xs, params)
    assert mixed.log_likelihood_at_poses(g, xs, params) == pytest.approx(want, abs=1e-12)
    assert np.ptp(want) > 0  # the classes differ: the sums are not all at the floor


def test_the_planners_table_is_kept_beside_the_model_and_read_back(tmp_path, monkeypatch):
    lik = two_classes()
    lik.table_dir = tmp_path
    params = LikelihoodParams()
    first = lik.training_log_likelihoods(params)
    kept = lik.table_file(params)
    assert kept is not None and kept.is_file() and kept.parent == tmp_path
    again = two_classes()
    again.table_dir = tmp_path

    def no_compute(*a):
        raise AssertionError("computed though it was kept")

    monkeypatch.setattr(GraspLikelihood, "_table", no_compute)
    np.testing.assert_array_equal(again.training_log_likelihoods(params), first)
    # Other widths or other grasps: another file, never the kept table.
    assert again.table_file(LikelihoodParams(floor=1e-2)) != kept
    other = GraspLikelihood.fit([(np.stack([pose_at(0.0)]), [grasp([1])])] * 2)
    other.table_dir = tmp_path
    assert other.table_file(params) != kept


def test_a_damaged_or_unwritable_table_is_computed_again(tmp_path, caplog):
    lik = two_classes()
    lik.table_dir = tmp_path
    params = LikelihoodParams()
    want = lik.training_log_likelihoods(params)
    lik.table_file(params).write_bytes(b"not a table")
    fresh = two_classes()
    fresh.table_dir = tmp_path
    np.testing.assert_array_equal(fresh.training_log_likelihoods(params), want)
    assert "computing it again" in caplog.text
    nowhere = two_classes()
    nowhere.table_dir = tmp_path / "missing" / "dir"  # cannot be written: memory only
    np.testing.assert_array_equal(nowhere.training_log_likelihoods(params), want)


def test_the_planners_table_averaged_over_placements():
    from activetouch.recognition.grasp_likelihood import placement_offsets, poses_under_offsets

    lik = two_classes()
    params = LikelihoodParams()
    plain = lik.training_log_likelihoods(params)
    np.testing.assert_allclose(
        lik.training_log_likelihoods(params, np.zeros((1, 3))), plain
    )  # the believed placement alone: the table
    off = placement_offsets(0.3, 0.0)
    assert off.shape == (9, 3) and not off[0].any() and np.abs(off).max() == 0.3
    assert placement_offsets(0.0, 0.0).shape == (0, 3)
    # Moved by 0.3 in x the object brings the other training pose under the hand: the
    # full grasp at x = 0 (class 0's alone) is then also explained where both classes feel
    # alike, so it tells class 0 from class 1 by less.
    blurred = lik.training_log_likelihoods(params, off)
    assert not np.allclose(blurred, plain)
    full = 0  # class 0's grasp(FULL) at x = 0
    assert blurred[full, 0] - blurred[full, 1] < plain[full, 0] - plain[full, 1]
    x = pose_at(0.1)
    moved = poses_under_offsets(x, np.array([[0.02, -0.01, 0.0], [0.0, 0.0, np.pi / 2]]))
    np.testing.assert_allclose(moved[0, :3], x[:3] - [0.02, -0.01, 0.0])
    np.testing.assert_allclose(moved[1, :3], [0.0, -0.1, 0.2], atol=1e-12)  # turned back


def test_a_pose_placed_on_an_offset_object_is_undone_by_the_offset():
    from activetouch.recognition.grasp_likelihood import pose_at_offset, poses_under_offsets

    # The object 1 cm along x and turned 90 deg: a wrist 0.1 m along the object's x is 0.1 m
    # along the believed frame's y, plus the shift, and turned with it.
    x = np.array([0.1, 0.0, 0.2, 0.0, 0.0, 0.0, 1.0])
    placed = pose_at_offset(x, np.array([0.01, 0.0, np.pi / 2]))
    np.testing.assert_allclose(placed[:3], [0.01, 0.1, 0.2], atol=1e-12)
    s = np.sqrt(0.5)
    np.testing.assert_allclose(np.abs(placed[3:]), [0.0, 0.0, s, s], atol=1e-12)
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = rng.normal(size=4)
        pose = np.concatenate([rng.normal(size=3) * 0.1, q / np.linalg.norm(q)])
        off = np.array([*rng.uniform(-0.03, 0.03, 2), rng.uniform(-0.5, 0.5)])
        back = poses_under_offsets(pose_at_offset(pose, off), off[None])[0]
        np.testing.assert_allclose(back[:3], pose[:3], atol=1e-12)
        assert abs(abs(back[3:] @ pose[3:]) - 1.0) < 1e-12  # the same rotation


def test_finger_censor_takes_each_fingers_own_masked_sensors() -> None:
    # ReFlex: 9 per finger (0-8, 9-17, 18-26), the palm's 27-37 stop no finger.
    w = finger_censor(np.array([3, 14, 17, 30]), 9, 1)
    assert w[0].tolist() == [[2**3], [2**14 + 2**17], [0]]
    assert w[1].tolist() == [[2**9 - 1 - 2**3], [(2**18 - 2**9) - 2**14 - 2**17], [2**27 - 2**18]]
    assert finger_censor(np.array([30, 35]), 9, 1) is None  # palm only
    assert finger_censor(np.array([3]), 0, 1) is None  # layout not known
    assert finger_censor(None, 9, 1) is None
    # BarrettHand: 24 fingertip cells per finger, the palm's 72-95.
    w = finger_censor(np.array([23, 24, 71, 80]), 24, 2)
    assert w[0, :, 0].tolist() == [2**23, 2**24, 0]
    assert w[0, :, 1].tolist() == [0, 0, 2**7]


def test_a_finger_whose_training_stop_is_masked_may_close_past_it() -> None:
    # Class 0's finger 2 (sensors 9-17) stopped at 1.0 rad on sensor 14 (a lip); class 1's
    # closed on to 2.0 with nothing felt. Sensor 14 is dead now: the guarded close does not hear
    # it, so the finger closes on to 2.0 over the lip too, and that must not read as class 1.
    at = np.stack([pose_at(0.0)])
    lik = GraspLikelihood.fit(
        [(at, [grasp([14], (1.0, 1.0, 1.0))]), (at, [grasp([], (1.0, 2.0, 1.0))])]
    )
    p = LikelihoodParams(angle_sigma_rad=0.1, floor=1e-9)
    here = Pose(pose_at(0.0)[:3], IDENTITY)
    felt = grasp([], (1.0, 2.0, 1.0))
    dead = np.array([14])
    blind = lik.log_likelihood(felt, here, p, dead)  # the layout not given: as before
    assert blind[0] == pytest.approx(np.log(np.exp(-(1.0**2) / (2 * 0.1**2)) + 1e-9))
    assert blind[1] == pytest.approx(np.log(1.0 + 1e-9))
    heard = lik.log_likelihood(felt, here, p, dead, finger_sensors=9)
    assert heard[0] == pytest.approx(heard[1], abs=1e-9)  # no say either way
    # Closing less than the training grasp still counts against it, as does another finger.
    short = lik.log_likelihood(grasp([], (1.0, 0.7, 1.0)), here, p, dead, finger_sensors=9)
    assert short[0] == pytest.approx(np.log(np.exp(-(0.3**2) / (2 * 0.1**2)) + 1e-9))
    other = lik.log_likelihood(grasp([], (1.5, 2.0, 1.0)), here, p, dead, finger_sensors=9)
    assert other[0] == pytest.approx(np.log(np.exp(-(0.5**2) / (2 * 0.1**2)) + 1e-9))
    # The same through the many-pose path the pose belief uses.
    many = lik.log_likelihood_at_poses(felt, at, p, dead, finger_sensors=9)
    np.testing.assert_allclose(many[0], heard, rtol=1e-12)
    # A training finger that also felt an unmasked sensor (15) stopped about where it would
    # now: compared as usual.
    both = GraspLikelihood.fit(
        [(at, [grasp([14, 15], (1.0, 1.0, 1.0))]), (at, [grasp([], (1.0, 2.0, 1.0))])]
    )
    usual = both.log_likelihood(felt, here, p, dead, finger_sensors=9)
    assert usual[0] == pytest.approx(np.log(np.exp(-1 - 1.0**2 / (2 * 0.1**2)) + 1e-9))
