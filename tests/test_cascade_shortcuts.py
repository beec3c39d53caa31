"""The cascade's shortcuts decide what the plain computation decides: the per-scene parts Context.build
works out (the target's hull half-planes, the outline samples' cues, the box where the arm surely
reaches), the mask the cheap stages share, and the bands with one piece each."""

import dataclasses
import random

import numpy as np
import pytest
import shapely

from cell.cellconfig import default_cell
from cell.grasp import bands, cascade, shapes
from cell.grasp.candidates import candidate_points
from cell.grasp.cascade import STAGE_FUNCS, STAGES, Context, Pairs, run_cascade
from cell.grasp.height import grasp_z_mm
from cell.grasp.params import SynthesisParams
from cell.kinematics import box_surely_reachable, reachable_mask

CELL = default_cell()
PARAMS = SynthesisParams()
TARGETS = [shapes.rectangle("bar", 240, 60, (350, 0), 10), shapes.gear("gear", 30, 12, 4, (330, 60)),
           shapes.l_shape("ell", 70, 50, 18, (420, 150), 25), shapes.disc("ring", 30, (300, -120), hole_r_mm=12),
           shapes.rectangle("box", 50, 30, (300, 100), 30)]
NEIGHBOURS = [shapes.rectangle("post", 30, 30, (350, 50), 0, z_top_mm=60),
              shapes.rectangle("plate", 80, 40, (300, 100), 0, z_top_mm=3)]


@pytest.fixture(autouse=True)
def _errstate_as_in_the_cascade():
    with np.errstate(divide="ignore", invalid="ignore"):
        yield


def scene(target, obstacles=()):
    """The context as the planner builds it (with the samples' normals), one without them (the cues
    worked out for the pairs' points), and every pair of free outline points."""
    op, free = candidate_points(target, obstacles, PARAMS)
    idx = np.flatnonzero(free)
    vp = op.subset(idx)
    gz = grasp_z_mm(target.z_bottom_mm, target.z_top_mm, CELL.gripper)
    planned = Context.build(target, list(obstacles), CELL, PARAMS, gz, op.points, op.ring, op.normals)
    plain = Context.build(target, list(obstacles), CELL, PARAMS, gz, op.points, op.ring)
    return planned, plain, Pairs.of(vp.points, vp.normals, idx)


@pytest.mark.parametrize("target", TARGETS, ids=lambda p: p.id)
def test_points_beyond_the_hull_half_planes_are_outside_the_target(target):
    ctx = Context.build(target, [], CELL, PARAMS, 5.0)
    x0, y0, x1, y1 = shapely.bounds(ctx.target_geom)
    rng = np.random.default_rng(0)
    xy = np.stack([rng.uniform(x0 - 20, x1 + 20, 20000), rng.uniform(y0 - 20, y1 + 20, 20000)])
    out = ctx.surely_outside(xy)
    assert 0 < out.sum() < len(out)
    assert not shapely.contains_xy(ctx.target_geom, xy[0][out], xy[1][out]).any()
    far = ctx.surely_outside(xy, 3.0)
    assert (far <= out).all() and (shapely.distance(ctx.target_geom, shapely.points(xy[:, far].T)) > 3.0).all()


@pytest.mark.parametrize("target", TARGETS, ids=lambda p: p.id)
def test_the_samples_cues_are_the_pairs_points_own(target):
    planned, plain, P = scene(target)
    idx = np.arange(len(P))
    pt = P.ij.T.ravel()
    assert np.array_equal(cascade._row_cues(planned, P, pt, P.sample_index.take(pt)),
                          cascade._row_cues(plain, P, pt, P.sample_index.take(pt)))
    assert np.array_equal(cascade._outline_ahead(planned, P, idx), cascade._outline_ahead(plain, P, idx))


def test_the_samples_box_decides_the_reach_stage_as_the_points_box():
    for target in (*TARGETS, shapes.rectangle("edge", 80, 40, (590, 0), 30)):
        planned, _, P = scene(target)
        assert planned.samples_reachable == cascade._midpoints_surely_reachable(planned, planned.samples)
        if planned.samples_reachable:
            assert cascade._midpoints_surely_reachable(planned, P.points)


def test_every_point_of_a_surely_reachable_box_is_reachable():
    """Random links, joint limits, J4 ranges and boxes: wherever box_surely_reachable says so, the
    solver reaches every point (corners, sides, inside) along any axis."""
    rng, nrng = random.Random(1), np.random.default_rng(1)
    certified = 0
    for _ in range(3000):
        j1, j2, c1, c2 = rng.uniform(20, 180), rng.uniform(20, 170), rng.uniform(-40, 40), rng.uniform(-30, 30)
        scara = dataclasses.replace(CELL.scara, l1_mm=rng.uniform(150, 400), l2_mm=rng.uniform(150, 400),
                                    j1_deg=(c1 - j1, c1 + j1), j2_deg=(c2 - j2, c2 + j2),
                                    j4_deg=rng.choice([(-360.0, 360.0), (-91.0, 91.0)]))
        x0, y0 = rng.uniform(1, 500), rng.uniform(-400, 300)
        x1, y1 = x0 + rng.uniform(1, 300), y0 + rng.uniform(1, 300)
        if not box_surely_reachable(x0, y0, x1, y1, 10.0, scara):
            continue
        certified += 1
        x = np.concatenate([nrng.uniform(x0, x1, 200), [x0, x0, x1, x1], np.full(10, x0), np.full(10, x1)])
        y = np.concatenate([nrng.uniform(y0, y1, 200), [y0, y1, y0, y1], nrng.uniform(y0, y1, 20)])
        assert reachable_mask(x, y, 10.0, nrng.uniform(-180, 180, len(x)), scara).all()
    assert certified > 100
    assert not box_surely_reachable(300, -20, 340, 20, 10.0, dataclasses.replace(CELL.scara, j4_deg=(-90.0, 90.0)))
    assert not box_surely_reachable(300, -20, 340, 20, 250.0, CELL.scara)  # above J3's range


@pytest.mark.parametrize("seed", range(4))
def test_a_box_is_not_certified_where_j1_would_have_to_wrap(seed):
    """J1 limits past +-180 deg and a forearm longer than the upper arm (beta passes 90 deg), boxes near the
    base: the solver wraps J1 into [-180, 180), so the box test must not certify a J1 it reads unwrapped."""
    scara = dataclasses.replace(CELL.scara, l1_mm=100.0, l2_mm=300.0, j1_deg=(-300.0, 100.0), j2_deg=(-150.0, 179.0),
                                j3_mm=(0.0, 200.0), j4_deg=(-360.0, 360.0))
    assert not box_surely_reachable(30, -210, 40, -200, 10.0, scara)  # certified before, unreachable everywhere
    assert not reachable_mask(np.array([35.0]), np.array([-205.0]), 10.0, np.array([0.0]), scara).any()
    rng, nrng = random.Random(seed), np.random.default_rng(seed)
    for _ in range(2000):
        x0, y0 = rng.uniform(1, 150), rng.uniform(-380, 300)
        x1, y1 = x0 + rng.uniform(1, 40), y0 + rng.uniform(1, 40)
        if box_surely_reachable(x0, y0, x1, y1, 10.0, scara):
            x = np.concatenate([nrng.uniform(x0, x1, 50), [x0, x0, x1, x1]])
            y = np.concatenate([nrng.uniform(y0, y1, 50), [y0, y1, y0, y1]])
            assert reachable_mask(x, y, 10.0, nrng.uniform(-180, 180, len(x)), scara).all()


def _through(ctx, P, last):
    """The pairs that reach the stage after `last` (the cascade's own stages, in order)."""
    alive = np.arange(len(P))
    for name in STAGES[:STAGES.index(last) + 1]:
        alive = alive.compress(STAGE_FUNCS[name](ctx, P, alive))
    return alive


@pytest.mark.parametrize("target", TARGETS, ids=lambda p: p.id)
def test_the_ik_box_passes_what_the_solver_passes(target):
    planned, _, P = scene(target)
    assert planned.ik_box is not None
    idx = _through(planned, P, "contacts")
    solved = dataclasses.replace(planned, ik_box=None)
    assert np.array_equal(cascade.stage_ik(planned, P, idx), cascade.stage_ik(solved, P, idx))
    outside = dataclasses.replace(planned, ik_box=(0.0, 0.0, 1.0, 1.0))  # no centre in it: solved as before
    assert np.array_equal(cascade.stage_ik(outside, P, idx), cascade.stage_ik(solved, P, idx))


def _plain_cascade(ctx, P):
    """The cascade as it was before the mask: each stage on the indices of the survivors."""
    alive, verdicts, kept, exact = np.arange(len(P)), [], {}, 0
    for name in STAGES:
        if name in cascade.EXACT_STAGES:
            exact += len(alive)
        ok = STAGE_FUNCS[name](ctx, P, alive) if len(alive) else np.zeros(0, bool)
        if not ok.all():
            verdicts.append((STAGES.index(name), alive, ok))
            alive = alive.compress(ok)
        kept[name] = len(alive)
    return cascade.CascadeResult(len(P), alive, verdicts, kept, exact, {})


@pytest.mark.parametrize("obstacles", [(), NEIGHBOURS], ids=["alone", "neighbours"])
@pytest.mark.parametrize("target", TARGETS + [shapes.rectangle("wide", 75, 20, (350, 0), 5)], ids=lambda p: p.id)
def test_the_masked_cheap_stages_keep_and_reject_what_the_plain_loop_does(target, obstacles):
    planned, _, P = scene(target, obstacles)
    masked, plain = run_cascade(planned, P), _plain_cascade(planned, P.fresh())
    assert np.array_equal(masked.survivors, plain.survivors)
    assert masked.kept == plain.kept and masked.exact_checks == plain.exact_checks
    assert np.array_equal(masked.rejected_by, plain.rejected_by)


@pytest.mark.parametrize("middle", [False, True], ids=["all", "middle"])
@pytest.mark.parametrize("target", TARGETS, ids=lambda p: p.id)
def test_one_piece_per_band_gives_what_the_per_band_scatters_give(target, middle):
    planned, _, P = scene(target)
    idx = _through(planned, P, "precheck")
    if middle:  # the pairs across the middle of the part: on the bar one piece of a face per band
        c = np.asarray(shapely.centroid(planned.target_geom).coords[0])
        idx = idx[np.hypot(*(P.m[idx] - c).T) < 10]
    m, u, t = P.m[idx], P.u[idx], P.t[idx]
    band = bands.BandEdges.clip(planned, *cascade._pad_bands(planned, u, t, m[:, 0], m[:, 1], 1.0 - 1e-6))
    scattered = dataclasses.replace(band, one_each=False)
    for slanted in (True, False):
        T, (x, y, w) = band.first_touch(planned, slanted)
        T2, (x2, y2, w2) = scattered.first_touch(planned, slanted)
        assert all(np.array_equal(a, b, equal_nan=True) for a, b in ((T, T2), (x, x2), (y, y2), (w, w2)))
    tl = (x - band.cx) * band.ux + (y - band.cy) * band.uy, (x - band.cx) * band.vx + (y - band.cy) * band.vy
    assert all(np.array_equal(a, b, equal_nan=True)
               for a, b in zip(band.on_material(None, *tl), scattered.on_material(None, *tl), strict=True))
    assert band.one_each or not (middle and target.id == "bar")


def _scara(l1, l2, j1, j2, j4):
    return dataclasses.replace(CELL.scara, l1_mm=l1, l2_mm=l2, j1_deg=j1, j2_deg=j2, j3_mm=(0.0, 200.0), j4_deg=j4)


def _grid(x0, y0, x1, y1, n=41):
    x, y = np.meshgrid(np.linspace(x0, x1, n), np.linspace(y0, y1, n))
    return x.ravel(), y.ravel()


# Found in a mutation pass: each box below was certified by a mutant of one term of the test (the term in
# the comment dropped or changed) although the solver does not reach some of its points.
@pytest.mark.parametrize(("box", "z_mm", "scara"), [
    ((300.0, -20.0, 340.0, 20.0), -1.0, CELL.scara),  # z below J3's range
    ((-185.105, -254.874, 71.209, -78.817), 10.0, _scara(262.179, 367.637, (-180.722, 129.869), (-171.284, 153.946),
                                                         (-90.5, 90.5))),  # x0 <= 0: left of the base
    ((351.941, -112.908, 355.581, 116.602), 10.0, _scara(283.659, 157.642, (-10.062, 109.784), (-74.056, 109.762),
                                                         (-90.5, 90.5))),  # across y = 0: the nearest point is on it
    ((198.103, -269.685, 471.058, -69.56), 10.0, _scara(373.506, 183.442, (-74.775, 235.328), (-118.71, 220.649),
                                                        (-91.0, 91.0))),  # beta's maximum inside the elbow range
    ((42.99, 213.95, 68.11, 224.72), 10.0, _scara(100.0, 300.0, (-100.0, 300.0), (-179.0, 150.0),
                                                  (-360.0, 360.0))),  # J1 past +180 (the solver wraps it)
    ((409.271, -387.963, 571.08, -243.52), 10.0, _scara(299.152, 392.219, (-253.371, 51.021), (42.161, 148.981),
                                                        (-360.0, 360.0))),  # elbow up: J2's lower limit
    ((477.986, -71.139, 541.74, 9.813), 10.0, _scara(226.969, 390.421, (24.47, 173.113), (-126.507, -91.236),
                                                     (-360.0, 360.0))),  # elbow down: J2's upper limit
])
def test_a_box_with_an_unreachable_point_is_not_certified(box, z_mm, scara):
    x, y = _grid(*box)
    assert not reachable_mask(x, y, z_mm, np.zeros(len(x)), scara).all()
    assert not box_surely_reachable(*box, z_mm, scara)


# ... and these, reachable everywhere, were not certified by a mutant (the shortcut lost, the solver runs)
@pytest.mark.parametrize(("box", "scara"), [
    ((300.0, -20.0, 340.0, 20.0), dataclasses.replace(CELL.scara, j4_deg=(-90.5, 90.5))),  # J4 spans 181 deg
    ((255.513, 146.883, 271.253, 232.292), _scara(266.675, 204.821, (-14.692, 183.602), (-99.983, 146.647),
                                                  (-360.0, 360.0))),  # beta's maximum outside the elbow range
    ((293.901, -97.813, 337.271, -95.04), _scara(258.18, 195.379, (-212.83, 107.441), (-199.194, 83.126),
                                                 (-91.0, 91.0))),  # elbow down only
    ((280.017, -230.818, 429.842, 64.47), _scara(379.372, 267.864, (-122.807, 118.173), (-85.153, 176.556),
                                                 (-91.0, 91.0))),  # elbow up only
])
def test_a_box_reachable_by_one_elbow_is_certified(box, scara):
    x, y = _grid(*box)
    for axis_deg in (-90.0, 0.0, 45.0, 90.0):
        assert reachable_mask(x, y, 10.0, np.full(len(x), axis_deg), scara).all()
    assert box_surely_reachable(*box, 10.0, scara)


def test_the_ik_box_is_the_targets_bounds_5_mm_wider_inside_the_workspace_and_surely_reachable():
    from cell.grasp.pairs import _ik_box

    square = shapely.box(330.0, -10.0, 350.0, 10.0)
    assert _ik_box(square, CELL, 10.0) == (325.0, -15.0, 355.0, 15.0)
    assert _ik_box(square, CELL, 250.0) is None  # above J3's range: nothing there is reachable
    x1 = CELL.workspace.x_mm[1]
    near_edge = shapely.box(x1 - 30.0, -10.0, x1 - 2.0, 10.0)  # in the workspace, its 5 mm margin is not
    assert box_surely_reachable(*near_edge.bounds, 10.0, CELL.scara)
    assert _ik_box(near_edge, CELL, 10.0) is None
    assert _ik_box(shapely.box(x1 - 30.0, -10.0, x1 - 5.0, 10.0), CELL, 10.0) == (x1 - 35.0, -15.0, x1, 15.0)
