"""Symmetries of planar targets (board_symmetry) and the turns that make two cameras' corner
numberings agree (view_consistency.resolve_turns), on synthetic poses."""

from __future__ import annotations

import re

import cv2
import numpy as np
import pytest

from microcal.vision.board_symmetry import (
    ambiguous_turns,
    colour_decides,
    turn_ids,
    turn_transform,
)
from microcal.vision.targets import parse_target
from microcal.vision.view_consistency import AGREEMENT_DEG, relative_rotation, resolve_turns

# spec -> (turns with colour, turns without colour)
EXPECTED_TURNS = {
    "chessboard:6x4:25000": ([0, 180], [0, 180]),  # even x even
    "chessboard:5x3:25000": ([0, 180], [0, 180]),  # odd x odd
    "chessboard:7x4:25000": ([0], [0, 180]),  # odd x even: colours decide 180
    "chessboard:4x7:300": ([0], [0, 180]),
    "chessboard:4x4:400": ([0, 90, 180, 270], [0, 90, 180, 270]),  # square, even
    "chessboard:5x5:400": ([0, 180], [0, 90, 180, 270]),  # square, odd: colours decide 90, 270
    "chessboard:6x6:1000": ([0, 90, 180, 270], [0, 90, 180, 270]),
    "dotgrid:40x30:250": ([0, 180], [0, 180]),
    "dotgrid:5x4:250": ([0, 180], [0, 180]),
    "dotgrid:5x5:250": ([0, 90, 180, 270], [0, 90, 180, 270]),
    "dotgrid:4x4:250": ([0, 90, 180, 270], [0, 90, 180, 270]),
    "charuco:5x4:10000": ([0], [0]),
    "charuco:5x5:10000": ([0], [0]),
    "charuco:6x4:10000": ([0], [0]),
}
SPECS = sorted(EXPECTED_TURNS)


def _turns(spec: str) -> list[tuple[str, int]]:
    return [(spec, t) for t in EXPECTED_TURNS[spec][1]]


ALL_TURNS = [case for spec in SPECS for case in _turns(spec)]


@pytest.mark.parametrize("spec", SPECS)
def test_ambiguous_turns(spec):
    target = parse_target(spec)
    with_colour, without = EXPECTED_TURNS[spec]
    assert ambiguous_turns(target) == with_colour
    assert ambiguous_turns(target, with_colour=True) == with_colour
    assert ambiguous_turns(target, with_colour=False) == without


@pytest.mark.parametrize("spec", SPECS)
def test_colour_decides_is_what_the_colour_leaves_out(spec):
    target = parse_target(spec)
    with_colour, without = EXPECTED_TURNS[spec]
    for turn in without[1:]:
        assert colour_decides(target, turn) == (turn not in with_colour), turn
    if target.kind != "chessboard":
        assert not any(colour_decides(target, t) for t in (0, 90, 180, 270))


@pytest.mark.parametrize(
    "spec",
    [s for s in SPECS if s.startswith("chessboard")],
)
def test_colour_never_decides_the_identity(spec):
    assert colour_decides(parse_target(spec), 0) is False


@pytest.mark.parametrize(("spec", "turn"), ALL_TURNS)
def test_turn_ids_is_a_permutation(spec, turn):
    target = parse_target(spec)
    ids = turn_ids(target, turn)
    n = len(target.points_um())
    assert ids.shape == (n,)
    assert np.issubdtype(ids.dtype, np.integer)
    assert np.array_equal(np.sort(ids), np.arange(n))
    if turn == 0:
        assert np.array_equal(ids, np.arange(n))
    else:
        assert not np.array_equal(ids, np.arange(n))


@pytest.mark.parametrize(("spec", "turn"), ALL_TURNS)
def test_turn_transform_moves_each_feature_onto_its_new_number(spec, turn):
    target = parse_target(spec)
    p = target.points_um()
    ids = turn_ids(target, turn)
    R, t = turn_transform(target, turn)
    assert R.shape == (3, 3)
    assert t.shape == (3,)
    # A rotation about z by +turn (counter-clockwise), exactly: integer entries.
    c, s = round(np.cos(np.deg2rad(turn))), round(np.sin(np.deg2rad(turn)))
    assert np.array_equal(R, [[c, -s, 0], [s, c, 0], [0, 0, 1]])
    assert np.array_equal(R @ R.T, np.eye(3))
    assert np.linalg.det(R) == 1.0  # integer matrix: exact
    assert t[2] == 0.0
    # Tolerance: 1e-9 µm absolute per coordinate (float round-off of grid positions <= 1e5 µm).
    np.testing.assert_allclose(p @ R.T + t, p[ids], rtol=0, atol=1e-9)
    # The turn is about the centre of the pattern: the centre stays put (same tolerance).
    np.testing.assert_allclose(R @ target.centre_um + t, target.centre_um, rtol=0, atol=1e-9)


@pytest.mark.parametrize(("spec", "turn"), ALL_TURNS)
def test_a_turn_then_its_inverse_is_the_identity(spec, turn):
    target = parse_target(spec)
    back = (360 - turn) % 360
    n = len(target.points_um())
    ids, ids_back = turn_ids(target, turn), turn_ids(target, back)
    assert np.array_equal(ids[ids_back], np.arange(n))
    assert np.array_equal(ids_back[ids], np.arange(n))
    R, t = turn_transform(target, turn)
    Rb, tb = turn_transform(target, back)
    assert np.array_equal(R @ Rb, np.eye(3))
    # Tolerance: 1e-9 µm absolute (round-off) on the composed translation.
    np.testing.assert_allclose(R @ tb + t, np.zeros(3), rtol=0, atol=1e-9)
    # turn_deg is taken modulo 360.
    assert np.array_equal(turn_ids(target, turn + 360), ids)
    assert np.array_equal(turn_ids(target, turn - 360), ids)


def test_turns_compose_like_rotations():
    target = parse_target("chessboard:4x4:400")
    for a in (0, 90, 180, 270):
        for b in (0, 90, 180, 270):
            # Relabelling by a, then by b, is relabelling by a + b.
            assert np.array_equal(
                turn_ids(target, b)[turn_ids(target, a)], turn_ids(target, (a + b) % 360)
            )


@pytest.mark.parametrize("spec", ["chessboard:6x4:25000", "dotgrid:5x4:250", "chessboard:7x4:1"])
@pytest.mark.parametrize("turn", [90, 270, 45])
def test_quarter_turns_of_an_oblong_target_are_refused(spec, turn):
    with pytest.raises(ValueError, match="turn_deg"):
        turn_ids(parse_target(spec), turn)


def _square_colours(cols, rows):
    """Dark squares of the printed chessboard, as microcal's renderer draws it: square (a, b),
    a in 0..cols, b in 0..rows, spans ((a - 1) p, a p) x ((b - 1) p, b p) and is dark when
    a + b is even."""
    a, b = np.meshgrid(np.arange(cols + 1), np.arange(rows + 1), indexing="ij")
    return a.ravel(), b.ravel(), (a.ravel() + b.ravel()) % 2 == 0


@pytest.mark.parametrize(
    ("spec", "turn"), [c for c in ALL_TURNS if c[0].startswith("chessboard") and c[1] != 0]
)
def test_colours_are_kept_by_a_turn_exactly_when_they_do_not_decide_it(spec, turn):
    target = parse_target(spec)
    cols, rows = target.pattern_size
    p = target.pitch_um
    a, b, dark = _square_colours(cols, rows)
    centres = np.column_stack([(a - 0.5) * p, (b - 0.5) * p, np.zeros(a.size)])
    R, t = turn_transform(target, turn)
    moved = centres @ R.T + t
    na, nb = moved[:, 0] / p + 0.5, moved[:, 1] / p + 0.5
    # Each square lands on a square of the board: integer indices within 1e-9 (round-off).
    np.testing.assert_allclose(na, np.rint(na), rtol=0, atol=1e-9)
    np.testing.assert_allclose(nb, np.rint(nb), rtol=0, atol=1e-9)
    na, nb = np.rint(na).astype(int), np.rint(nb).astype(int)
    assert (na.min(), na.max()) == (0, cols)
    assert (nb.min(), nb.max()) == (0, rows)
    assert len(set(zip(na.tolist(), nb.tolist(), strict=True))) == a.size
    dark_there = (na + nb) % 2 == 0
    kept = dark_there == dark
    assert kept.all() or not kept.any()  # a turn keeps all colours or swaps them all
    assert bool(kept.all()) == (not colour_decides(target, turn))
    assert (turn in ambiguous_turns(target)) == bool(kept.all())


# --- resolve_turns on synthetic poses ------------------------------------------------------


def _rot(rvec):
    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))
    return R


def _rvec(R):
    r, _ = cv2.Rodrigues(np.asarray(R, dtype=np.float64))
    return r.ravel()


def _angle_deg(Ra, Rb):
    return float(np.degrees(np.arccos(np.clip((np.trace(Ra @ Rb.T) - 1) / 2, -1, 1))))


def _random_axis(rng):
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def _random_rotation(rng):
    """A rotation uniform over SO(3) (from a random unit quaternion)."""
    w, x, y, z = _random_unit_quaternion(rng)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip


def _random_unit_quaternion(rng):
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def _noisy(R, rng, noise_deg):
    return _rot(_random_axis(rng) * np.deg2rad(noise_deg)) @ R


def _board_rotation(rng, max_tilt_deg=40.0):
    """A board facing the camera, tilted up to max_tilt_deg about an in-plane axis and spun
    by any angle about its normal."""
    phi = rng.uniform(0, 2 * np.pi)
    tilt = np.deg2rad(rng.uniform(0, max_tilt_deg))
    spin = rng.uniform(0, 2 * np.pi)
    return _rot([np.cos(phi) * tilt, np.sin(phi) * tilt, 0.0]) @ _rot([0.0, 0.0, spin])


def _synthetic_views(target, rng, turns_b, *, noise_deg=0.3, n_views=10, max_tilt_deg=40.0):
    """Board rotations per view in camera A and B (Rodrigues), B's numbering turned in view v
    by ``turns_b[v]``: relabelling B's corner k to turn_ids(target, s)[k] changes B's estimated
    board rotation from R_b to R_b @ R_s.T."""
    R_ab = _random_rotation(rng)
    poses_a, poses_b = {}, {}
    for v in range(n_views):
        Ra = _board_rotation(rng, max_tilt_deg)
        Rb = R_ab @ Ra
        Rs, _ = turn_transform(target, turns_b.get(v, 0))
        poses_a[v] = _rvec(_noisy(Ra, rng, noise_deg))
        poses_b[v] = _rvec(_noisy(Rb @ Rs.T, rng, noise_deg))
    return R_ab, poses_a, poses_b


def test_relabelling_turns_the_estimated_board_rotation_as_the_synthetic_views_assume():
    """The conversion _synthetic_views uses, checked against solvePnP on projected corners:
    numbering B's corners k -> turn_ids(s)[k] gives the board rotation R_b @ R_s.T, and
    relative_rotation with the undoing turn (360 - s) gives back R_b @ R_a.T."""
    target = parse_target("chessboard:4x4:25000")
    K = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
    p = target.points_um() - target.centre_um
    rng = np.random.default_rng(7)
    Ra = _board_rotation(rng, 30.0)
    Rb = _rot([0.05, -0.2, 0.1]) @ Ra
    t = np.array([0.0, 0.0, 600_000.0])
    for s in (90, 180, 270):
        q, _ = cv2.projectPoints(p, _rvec(Rb), t, K, None)
        q = q.reshape(-1, 2)
        labelled = np.empty_like(q)
        labelled[turn_ids(target, s)] = q  # physical corner k now carries label ids[k]
        ok, rvec, _ = cv2.solvePnP(target.points_um(), labelled, K, None)
        assert ok
        Rs, _ = turn_transform(target, s)
        # Tolerance: 1e-4 deg between rotations (noise-free projections; solvePnP's
        # iterations stop at about 1e-6 deg).
        assert _angle_deg(_rot(rvec), Rb @ Rs.T) < 1e-4
        undo = (360 - s) % 360
        rel = relative_rotation(_rvec(Ra), rvec, target, undo)
        assert _angle_deg(rel, Rb @ Ra.T) < 1e-4  # same tolerance


def _undoing(turns_b, n_views):
    """The turn resolve_turns must report per view: the one whose relabelling undoes the
    turn applied to B's numbering."""
    return {v: (360 - turns_b.get(v, 0)) % 360 for v in range(n_views)}


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize(
    ("spec", "possible"),
    [("chessboard:6x4:25000", [180]), ("chessboard:4x4:25000", [90, 180, 270]),
     ("dotgrid:5x5:250", [90, 180, 270])],
)  # fmt: skip
def test_resolve_turns_recovers_the_turns_applied(spec, possible, seed):
    target = parse_target(spec)
    rng = np.random.default_rng(seed)
    n_views = 10
    turned = rng.choice(n_views, size=int(rng.integers(1, n_views)), replace=False)
    turns_b = {int(v): int(rng.choice(possible)) for v in turned}
    R_ab, poses_a, poses_b = _synthetic_views(target, rng, turns_b)
    res = resolve_turns(target, poses_a, poses_b)
    assert res.disagree == {}
    assert res.turns == _undoing(turns_b, n_views)
    assert res.turned == sorted(turns_b)
    # Tolerance: 1 deg between the agreed and the true relative rotation (each camera's pose
    # carries 0.3 deg of noise; the agreed rotation is one view's estimate).
    assert _angle_deg(res.rotation, R_ab) < 1.0


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("spec", ["chessboard:6x4:25000", "chessboard:4x4:25000"])
def test_consistent_views_are_not_turned(spec, seed):
    target = parse_target(spec)
    rng = np.random.default_rng(100 + seed)
    R_ab, poses_a, poses_b = _synthetic_views(target, rng, {})
    res = resolve_turns(target, poses_a, poses_b)
    assert res.turns == dict.fromkeys(range(10), 0)
    assert res.turned == []
    assert res.disagree == {}
    assert _angle_deg(res.rotation, R_ab) < 1.0  # tolerance: 1 deg, as above


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize(
    ("spec", "possible"),
    [("chessboard:6x4:25000", [180]), ("chessboard:4x4:25000", [90, 180, 270])],
)
def test_a_view_that_fits_no_turn_is_reported_with_its_angle(spec, possible, seed):
    target = parse_target(spec)
    rng = np.random.default_rng(200 + seed)
    n_views = 10
    turns_b = {1: int(rng.choice(possible)), 6: int(rng.choice(possible))}
    R_ab, poses_a, poses_b = _synthetic_views(target, rng, turns_b)
    bad = 3
    # Camera B's rotation in view 3 replaced by an unrelated one: 60 deg about a random axis
    # away from the true one, which no turn of the board brings within AGREEMENT_DEG.
    Rb_bad = _rot(_random_axis(rng) * np.deg2rad(60.0)) @ R_ab @ _rot(poses_a[bad])
    poses_b[bad] = _rvec(Rb_bad)
    expected_deg = min(
        _angle_deg(relative_rotation(poses_a[bad], poses_b[bad], target, u), R_ab)
        for u in ambiguous_turns(target)
    )
    assert expected_deg > AGREEMENT_DEG + 5  # the set-up: at least 5 deg beyond the threshold
    res = resolve_turns(target, poses_a, poses_b)
    assert set(res.disagree) == {bad}
    reason = res.disagree[bad]
    m = re.search(r"relative rotation in this view is (\d+\.\d) deg from the other views'", reason)
    assert m, reason
    # Tolerance: 1.5 deg between the angle named and the one to the true relative rotation
    # (the agreed rotation is off the true one by the pose noise, <= 0.6 deg, and the
    # message rounds to 0.1 deg).
    assert float(m.group(1)) == pytest.approx(expected_deg, abs=1.5)
    assert f"more than {AGREEMENT_DEG:g}" in reason
    expected = _undoing(turns_b, n_views)
    del expected[bad]
    assert res.turns == expected
    assert _angle_deg(res.rotation, R_ab) < 1.0  # tolerance: 1 deg, as above


def test_views_missing_in_either_camera_are_left_out():
    target = parse_target("chessboard:6x4:25000")
    rng = np.random.default_rng(5)
    _, poses_a, poses_b = _synthetic_views(target, rng, {2: 180})
    del poses_a[0]
    del poses_b[9]
    poses_b[42] = poses_b[1]
    res = resolve_turns(target, poses_a, poses_b)
    assert sorted(res.turns) == list(range(1, 9))
    assert res.turned == [2]
    assert res.disagree == {}


def test_no_common_view_gives_an_empty_resolution():
    target = parse_target("chessboard:6x4:25000")
    res = resolve_turns(target, {0: np.zeros(3)}, {1: np.zeros(3)})
    assert res.turns == {}
    assert res.disagree == {}
    assert res.turned == []
    assert np.array_equal(res.rotation, np.eye(3))


def test_boards_all_in_one_plane_keep_most_numberings_as_detected():
    """With every board in the same plane (no tilt) and no translations given, a turned
    numbering is indistinguishable from a turned relative pose by the rotation alone: the
    module keeps the numbering of most views, and says the decision was weak."""
    target = parse_target("chessboard:6x4:25000")
    rng = np.random.default_rng(11)
    turns_b = {0: 180, 4: 180, 7: 180}
    _, poses_a, poses_b = _synthetic_views(target, rng, turns_b, max_tilt_deg=0.0)
    res = resolve_turns(target, poses_a, poses_b)
    assert res.disagree == {}
    assert res.turned == sorted(turns_b)
    assert "told apart weakly" in res.note
    # The majority turned: now the other seven are the ones renumbered.
    turns_b = {v: 180 for v in range(10) if v not in (0, 4, 7)}
    _, poses_a, poses_b = _synthetic_views(target, rng, turns_b, max_tilt_deg=0.0)
    res = resolve_turns(target, poses_a, poses_b)
    assert res.turned == [0, 4, 7]


@pytest.mark.parametrize("max_tilt_deg", [3.0, 20.0])
def test_resolve_turns_uses_the_relative_translation_when_tilts_hardly_vary(max_tilt_deg):
    # With board normals within a few degrees, a wrong 180-degree turn changes the relative
    # rotation by little; the relative translation (a turn about each view's board centre
    # moves it) still tells. 6 of 10 views numbered from the other end in camera B.
    target = parse_target("chessboard:6x4:25000")
    Rs, ts = turn_transform(target, 180)
    for seed in range(10):
        rng = np.random.default_rng(seed)
        R_rel = cv2.Rodrigues(np.deg2rad(rng.uniform(-5, 5, 3)))[0]
        t_rel = np.array([-120_000.0, 0.0, 0.0])
        pa, pb, ta, tb = {}, {}, {}, {}
        for v in range(10):
            angles = np.deg2rad(rng.uniform(-max_tilt_deg, max_tilt_deg, 3)) * [1, 1, 0]
            Ra = cv2.Rodrigues(angles + [0, 0, np.deg2rad(rng.uniform(-20, 20))])[0]
            t_a = rng.uniform([-2e5, -1.5e5, 5e5], [2e5, 1.5e5, 9e5])
            Rb, t_b = R_rel @ Ra, R_rel @ t_a + t_rel
            if v < 6:  # camera B numbered this view from the other end
                Rb, t_b = Rb @ Rs.T, t_b - Rb @ Rs.T @ ts
            noisy = [cv2.Rodrigues(np.deg2rad(rng.normal(0, 0.3, 3)))[0] @ R for R in (Ra, Rb)]
            pa[v], pb[v] = (cv2.Rodrigues(R)[0].ravel() for R in noisy)
            ta[v], tb[v] = t_a + rng.normal(0, 500, 3), t_b + rng.normal(0, 500, 3)
        res = resolve_turns(target, pa, pb, (ta, tb))
        assert res.turned == list(range(6)), seed
        # Little tilt is said: the rotation alone could not have decided.
        assert ("tilt varies by only" in res.note) == (max_tilt_deg < 10)
