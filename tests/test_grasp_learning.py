"""Learning from examples: labels for both trees, the trees' readable rules, and behaviour that
follows the examples (not hard-coded)."""

import numpy as np
import pytest

from cell.cellconfig import default_cell
from cell.errors import BadInput
from cell.examples import GraspExample, append_examples, load_examples
from cell.grasp import shapes
from cell.grasp.learning import fit_model, point_training, set_attributes_of_example
from cell.grasp.params import SynthesisParams
from cell.grasp.synthesis import GraspPlanner
from cell.scene import Scene

CELL = default_cell()
PARAMS = SynthesisParams()
SRC = {"kind": "manual", "by": "test"}
RECT = shapes.rectangle("r", 60, 30)  # centred at (350, 0)


def ex(eid, contacts, valid, cv=None, part=RECT):
    return GraspExample(eid, part, np.array(contacts, float), valid, SRC, cv)


def test_an_accepted_grasp_labels_the_points_within_half_a_pad_of_its_contacts_valid():
    X, y = point_training(ex("a", [[350, 15], [350, -15]], True), PARAMS, 6.0)
    # 2 mm step, mid-step samples: 6 samples within 6 mm each side on each face
    assert len(y) == 12 and y.all()
    assert np.all(X[:, 0] <= np.hypot(6, 15) + 1e-9)


def test_contact_verdicts_label_each_side_and_a_bare_rejection_labels_nothing():
    X, y = point_training(ex("b", [[350, 15], [350, -15]], False, (True, False)), PARAMS, 6.0)
    assert len(y) == 12 and y.sum() == 6
    X2, y2 = point_training(ex("c", [[350, 15], [350, -15]], False), PARAMS, 6.0)
    assert len(y2) == 0


def test_each_example_is_a_set_augmented_with_its_neighbours():
    e = ex("a", [[350, 15], [350, -15]], True)
    assert set_attributes_of_example(e, PARAMS).shape == (1, 2 + 2 * len(PARAMS.scales_mm))
    aug = set_attributes_of_example(e, PARAMS, (-1, 0, 1))
    assert aug.shape[0] == 9
    assert np.allclose(aug[4], set_attributes_of_example(e, PARAMS)[0])  # the (0, 0) shift is the example


def test_fitting_refuses_examples_it_cannot_learn_from():
    with pytest.raises(BadInput, match="no accepted"):
        fit_model([ex("x", [[350, 15], [350, -15]], False)], PARAMS, 6.0)
    with pytest.raises(BadInput, match="contacts"):
        fit_model([ex("y", [[350, 15], [350, -15], [380, 0]], True)], PARAMS, 6.0)
    with pytest.raises(BadInput):
        fit_model([], PARAMS, 6.0)


def faces_examples():
    """Accept grasps across the long faces, reject across the ends."""
    big = shapes.rectangle("b", 70, 40)
    return [ex("f1", [[350, 15], [350, -15]], True), ex("f2", [[340, 15], [340, -15]], True),
            ex("f3", [[350, 20], [350, -20]], True, part=big),
            ex("e1", [[380, 0], [320, 0]], False, (False, False)),
            ex("e2", [[380, 8], [320, 8]], False, (False, False)),
            ex("e3", [[385, 0], [315, 0]], False, (False, False), part=big)]


def ends_examples():
    """The opposite teaching: accept across the ends, reject across the long faces."""
    big = shapes.rectangle("b", 70, 40)
    return [ex("e1", [[380, 0], [320, 0]], True), ex("e2", [[380, 6], [320, 6]], True),
            ex("e3", [[385, 0], [315, 0]], True, part=big),
            ex("f1", [[350, 15], [350, -15]], False, (False, False)),
            ex("f2", [[340, 15], [340, -15]], False, (False, False)),
            ex("f3", [[350, 20], [350, -20]], False, (False, False), part=big)]


@pytest.mark.parametrize("angle", [0.0, 35.0, -70.0])
def test_the_chosen_grasp_follows_the_teaching_on_an_unseen_size_and_pose(angle):
    part = shapes.rectangle("new", 56, 28, center=(300, 80), angle_deg=angle)
    scene = Scene((part,), "new")
    across_faces = GraspPlanner(CELL, faces_examples()).plan(scene).grasp
    across_ends = GraspPlanner(CELL, ends_examples()).plan(scene).grasp

    def axis_vs_long_side(g):
        d = abs((g.axis_deg - angle + 90) % 180 - 90)
        return d

    assert axis_vs_long_side(across_faces) == pytest.approx(90, abs=1e-6)
    assert axis_vs_long_side(across_ends) == pytest.approx(0, abs=1e-6)
    assert across_faces.opening_mm == pytest.approx(28, abs=0.01)
    assert across_ends.opening_mm == pytest.approx(56, abs=0.01)


def test_rules_are_readable_and_say_what_the_tree_does():
    planner = GraspPlanner(CELL, faces_examples())
    rules = planner.rules()
    assert rules["points"] and rules["sets"]
    names = ("dist_cog", "convexity_", "centre_offset", "angle_")
    assert all(any(n in r for n in names) or r.startswith("ALWAYS") for r in rules["points"] + rules["sets"])
    rng = np.random.default_rng(1)
    for tree, dim in ((planner.model.point_tree, 2 + len(PARAMS.scales_mm)),
                      (planner.model.set_tree, 2 + 2 * len(PARAMS.scales_mm))):
        X = rng.normal(size=(50, dim)) * np.r_[30, 1, [0.3] * (dim - 2)]
        for x, verdict in zip(X, tree.predict(X), strict=True):
            rule = tree.rule_for(x)
            said = rule.split(" THEN ")[1] if " THEN " in rule else rule[len("ALWAYS "):]
            assert said.startswith("valid" if verdict else "invalid")
    assert planner.model.point_tree.tree_ is not None  # a real tree, with contrast to learn from


def test_trees_are_rebuilt_identically_from_the_example_file(tmp_path):
    path = tmp_path / "ex.jsonl"
    append_examples(path, faces_examples())
    a = GraspPlanner(CELL, load_examples(path))
    b = GraspPlanner(CELL, load_examples(path))
    assert a.rules() == b.rules()
    scene = Scene((shapes.l_shape("l", 70, 50, 18, (420, 150), 25),), "l")
    ga, gb = a.plan(scene).grasp, b.plan(scene).grasp
    assert np.array_equal(ga.contacts_mm, gb.contacts_mm) and ga.joints == gb.joints


def test_the_chosen_set_is_the_valid_set_nearest_to_an_accepted_example():
    planner = GraspPlanner(CELL, faces_examples())
    res = planner.plan(Scene((shapes.rectangle("t", 60, 30, (320, -60)),), "t"))
    d = [g.distance_to_example for g in res.ranked]
    assert d == sorted(d) and res.grasp is res.ranked[0]
    assert len(res.ranked) == res.counts["valid_sets"] == int(res.set_valid.sum())
    # the same part as an example: the nearest set is that example's own grasp, at distance ~0
    assert res.grasp.distance_to_example < 0.05
    assert np.allclose(sorted(res.grasp.contacts_mm[:, 0]), [320, 320], atol=2.1)
