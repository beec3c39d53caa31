"""Learning from examples: labels for both trees, the trees, and their readable rules.

How an example teaches (paper: the operator grasps parts in a simulation environment):
- Tree 1 (points). The example's part outline is resampled at the planner's step; the
  candidate points on the same ring within half a pad width (along the outline) of a
  contact (projected onto the outline) that its pad touches take that contact's label:
  `contact_valid[i]` when given, else true for an accepted grasp; a rejected grasp without
  `contact_valid` says nothing about its points (the operator may have rejected it for a
  reason that is not the contact's shape).
- Tree 2 (sets). Each example is one set, labelled by `valid`, with its global attributes
  measured at the contacts projected onto the outline; it is augmented with its
  neighbouring sets (each contact shifted by -k..k steps along the outline, all
  combinations), which a pad 6 steps wide could not tell apart. A rejected example that
  names a bad contact (`contact_valid` has a false) was rejected for that contact: tree 1
  learns it, and it is not a negative set for tree 2, because its global attributes may be
  those of a good set (a centred, antipodal grasp across the wrong faces looks, globally,
  exactly like the centred grasp across the right ones; as a negative set it would
  contradict the accepted example and cancel it).
- Selection uses the accepted examples' own (unaugmented) global attributes and, weighted by
  `SynthesisParams.part_shape_weight`, their parts' shape (attributes.part_attributes): a set is
  compared with the examples taken on parts of its part's kind first (nearest_example).
Trees are rebuilt from the example file on every start (milliseconds): no pickles.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from sklearn.tree import DecisionTreeClassifier

from cell.errors import BadInput
from cell.examples import GraspExample
from cell.grasp.attributes import (
    describe_points,
    global_attributes,
    global_names,
    local_attributes,
    local_names,
    part_attributes,
)
from cell.grasp.outline import part_rings, project_to_outline, resample
from cell.grasp.params import SynthesisParams


def contact_labels(ex: GraspExample) -> list[bool | None]:
    if ex.contact_valid is not None:
        return list(ex.contact_valid)
    return [True if ex.valid else None] * ex.n_contacts


def point_training(ex: GraspExample, params: SynthesisParams, half_pad_mm: float):
    """(X (k, F), y (k,)) for tree 1 from one example."""
    rings = part_rings(ex.part)
    ring_idx, arc = resample(rings, params.step_mm)
    rows, labels = [], []
    op = None
    contacts = np.asarray(ex.contacts_mm, float)
    proj = [project_to_outline(rings, c) for c in contacts]
    if params.label_from_outline:
        # a contact given off the outline (the reader takes up to MAX_CONTACT_OFFSET_MM) touches the outline where
        # it projects: compared raw, a contact 1.5 mm out was more than TOUCH_DEPTH_MM from every point and
        # labelled none
        contacts = np.array([rings[r].at(s) for r, s, _ in proj])
    for c, lab, (r, s, _) in zip(contacts, contact_labels(ex), proj, strict=True):
        if lab is None:
            continue
        L = rings[r].length_mm
        d = np.abs((arc - s + L / 2) % L - L / 2)  # periodic arc distance
        sel = (ring_idx == r) & (d <= half_pad_mm)
        if not sel.any():
            continue
        if op is None:
            op = describe_points(rings, ring_idx, arc, params.scales_mm)
            X_all = local_attributes(op, ex.part, params.cog_radius_outer_disc, params.closed_slit_mm)
        if params.label_touched_only:
            sel &= _touched(op.points, c, contacts, half_pad_mm)
            if not sel.any():
                continue
        rows.append(X_all[sel])
        labels.append(np.full(sel.sum(), lab))
    if not rows:
        return np.zeros((0, 2 + len(params.scales_mm))), np.zeros(0, bool)
    return np.vstack(rows), np.concatenate(labels)


TOUCH_DEPTH_MM = 1.0  # outline this far behind a pad's face (along the closing axis) is not touched by it


def _touched(points: np.ndarray, c: np.ndarray, contacts: np.ndarray, half_pad_mm: float) -> np.ndarray:
    """(z,) bool: outline points the pad seated at contact c touches: under the pad (within
    half_pad_mm across the closing axis) and at most TOUCH_DEPTH_MM behind its face. The
    closing axis points from the contacts' centroid to c (for two jaws: from the other contact).
    Across gear teeth or a notch the pad rests on the tips: the roots under it are not what
    the operator chose to hold, so they get no label."""
    a = c - contacts.mean(axis=0)
    a = a / max(float(np.linalg.norm(a)), 1e-12)
    rel = points - c
    depth = -(rel @ a)  # behind the face, into the part
    lateral = np.abs(rel[:, 0] * a[1] - rel[:, 1] * a[0])
    return (lateral <= half_pad_mm + 1e-9) & (np.abs(depth) <= TOUCH_DEPTH_MM)


def set_attributes_of_example(ex: GraspExample, params: SynthesisParams, shifts=(0,)) -> np.ndarray:
    """Global attributes (m, G) of the example's set and of its shifted neighbours."""
    rings = part_rings(ex.part)
    proj = [project_to_outline(rings, c) for c in ex.contacts_mm]
    combos = list(itertools.product(shifts, repeat=len(proj)))
    ring_idx = np.array([[p[0] for p in proj]] * len(combos)).ravel()
    arc = np.array([[p[1] + k * params.step_mm for p, k in zip(proj, combo, strict=True)]
                    for combo in combos]).ravel()
    op = describe_points(rings, ring_idx, arc, params.scales_mm)
    n = len(proj)
    return global_attributes(op.points.reshape(-1, n, 2), op.chord_normals.reshape(len(combos), n, -1, 2), ex.part,
                             params.cog_radius_outer_disc, params.closed_slit_mm, params.vertex_order_free)


class AttributeTree:
    """A decision tree over named attributes, printable as if-then rules (scikit-learn style:
    hyperparameters in __init__, learned state ends in _)."""

    def __init__(self, names: list[str], max_depth: int = 4, min_samples_leaf: int = 2,
                 minority_weight_max: float = 0.0):
        self.names = names
        self.max_depth = max_depth
        self.min_samples_leaf = min_samples_leaf
        self.minority_weight_max = minority_weight_max  # SynthesisParams.tree_minority_weight_max (0: unbounded)

    def fit(self, X, y) -> AttributeTree:
        X = np.asarray(X, float).reshape(-1, len(self.names))
        y = np.asarray(y, bool)
        self.n_samples_ = len(y)
        self.n_valid_ = int(y.sum())
        if len(set(y.tolist())) < 2:
            # No contrast to learn from: every input gets the one verdict the examples show
            # (no examples at all: nothing is ruled out).
            self.constant_ = bool(y[0]) if len(y) else True
            self.tree_ = None
            return self
        self.constant_ = None
        self.tree_ = DecisionTreeClassifier(max_depth=self.max_depth, min_samples_leaf=self.min_samples_leaf,
                                            class_weight="balanced", random_state=0).fit(X, y)
        # the training rows of each class (classes_ order) under each node, counted: what the rules say
        t = self.tree_.tree_
        rows = np.zeros((t.node_count, 2))
        np.add.at(rows, (t.apply(np.ascontiguousarray(X, np.float32)), y.astype(int)), 1)
        for node in range(t.node_count - 1, -1, -1):  # children come after their parent
            if t.children_left[node] != -1:
                rows[node] = rows[t.children_left[node]] + rows[t.children_right[node]]
        self.rows_ = rows
        # each class's weight in a leaf's vote: balanced (a rejection weighs n_valid / n_invalid accepted rows),
        # with the rarer class's weight bounded by minority_weight_max
        n = rows[0]
        w = n.sum() / np.maximum(2 * n, 1)
        if self.minority_weight_max > 0:
            w = np.minimum(w / w.min(), self.minority_weight_max)
        self.vote_weight_ = w
        return self

    def predict(self, X) -> np.ndarray:
        X = np.asarray(X, float).reshape(-1, len(self.names))
        if self.tree_ is None:
            return np.full(len(X), self.constant_)
        # the fitted tree's own apply (DecisionTreeClassifier.apply's result without its input
        # validation, which costs 25 times the look-up on a few hundred rows): float32 rows, as it takes them
        return self._leaf_class()[self.tree_.tree_.apply(np.ascontiguousarray(X, np.float32))]

    def _weights(self) -> np.ndarray:
        """(nodes, 2) each node's weight per class in its vote: balanced (sklearn's own), or from the counted
        rows with the rarer class's weight bounded (minority_weight_max)."""
        if self.minority_weight_max > 0:
            return self.rows_ * self.vote_weight_
        return self.tree_.tree_.value[:, 0, :]

    def _leaf_class(self) -> np.ndarray:
        return self.tree_.classes_[np.argmax(self._weights(), axis=1)].astype(bool)

    def _path_rules(self):
        """[(leaf nodes, [condition strings], verdict, (invalid rows, valid rows), share of the verdict's
        weight)], one per rule.

        Sibling subtrees whose leaves all give the same verdict are merged into one rule (the
        split does not change the decision, only the purity), so every printed rule decides."""
        t = self.tree_.tree_
        cls = self._leaf_class()
        weights = self._weights()

        def verdicts(node):
            if t.children_left[node] == -1:
                return {bool(cls[node])}
            return verdicts(t.children_left[node]) | verdicts(t.children_right[node])

        def leaves(node):
            if t.children_left[node] == -1:
                return [node]
            return leaves(t.children_left[node]) + leaves(t.children_right[node])

        out = []

        def walk(node, conds):
            v = verdicts(node)
            if len(v) == 1:
                ls = leaves(node)
                w = weights[node]
                k = int(np.flatnonzero(self.tree_.classes_ == next(iter(v)))[0])
                rows = dict(zip(self.tree_.classes_.tolist(), self.rows_[node].tolist(), strict=True))
                out.append((ls, conds, next(iter(v)), (int(rows.get(False, 0)), int(rows.get(True, 0))),
                            float(w[k] / max(w.sum(), 1e-12))))
                return
            name, thr = self.names[t.feature[node]], t.threshold[node]
            walk(t.children_left[node], conds + [f"{name} <= {thr:.3f}"])
            walk(t.children_right[node], conds + [f"{name} > {thr:.3f}"])

        walk(0, [])
        return out

    def rules(self) -> list[str]:
        if self.tree_ is None:
            # training rows (labelled points or sets), as in the other rules: not the examples
            why = "no labelled training rows" if self.n_samples_ == 0 else f"all {self.n_samples_} training rows agree"
            return [f"ALWAYS {'valid' if self.constant_ else 'invalid'}  ({why})"]
        return [self._format(c, v, rows, share) for _, c, v, rows, share in self._path_rules()]

    def rule_for(self, x) -> str:
        """The rule (leaf path) that decides one attribute row."""
        if self.tree_ is None:
            return self.rules()[0]
        leaf = int(self.tree_.apply(np.asarray(x, np.float32).reshape(1, -1))[0])
        for nodes, c, v, rows, share in self._path_rules():
            if leaf in nodes:
                return self._format(c, v, rows, share)
        raise AssertionError("leaf not found")

    @staticmethod
    def _format(conds, verdict, rows, share) -> str:
        # one bound per attribute and side: the tightest along the path
        bounds: dict = {}
        for c in conds:
            name, op, thr = c.split(" ")
            key, thr = (name, op), float(thr)
            bounds[key] = thr if key not in bounds else (min if op == "<=" else max)(bounds[key], thr)
        conds = [f"{name} {op} {thr:.3f}" for (name, op), thr in bounds.items()]
        head = "IF " + " AND ".join(conds) if conds else "ALWAYS"
        invalid, valid = rows
        return (f"{head} THEN {'valid' if verdict else 'invalid'}  ({invalid + valid} training rows: "
                f"{invalid} invalid / {valid} valid, {share:.0%} of their weight)")


@dataclass
class LearnedModel:
    point_tree: AttributeTree
    set_tree: AttributeTree
    example_attrs: np.ndarray  # (e, G) accepted examples' global attributes
    example_ids: list[str]
    scale: np.ndarray  # (G,) normalisation of the global-attribute space
    counts: dict
    example_parts: np.ndarray | None = None  # (e, P) accepted examples' parts' shape (attributes.part_attributes)
    part_scale: np.ndarray | None = None  # (P,) normalisation of the part-shape space
    part_weight: float = 0.0  # SynthesisParams.part_shape_weight


def fit_model(examples: list[GraspExample], params: SynthesisParams, half_pad_mm: float) -> LearnedModel:
    if not examples:
        raise BadInput("no examples: the planner learns only from examples")
    for ex in examples:
        if ex.n_contacts != params.n_contacts:
            raise BadInput(f"example {ex.id!r} has {ex.n_contacts} contacts; this gripper takes "
                           f"{params.n_contacts}")
    if not any(ex.valid for ex in examples):
        raise BadInput("the examples hold no accepted (valid) grasp: the planner needs at least one to imitate")
    Xp, yp = zip(*(point_training(ex, params, half_pad_mm) for ex in examples), strict=True)
    Xp, yp = np.vstack(Xp), np.concatenate(yp)
    k = params.augment_shift_steps
    shifts = tuple(range(-k, k + 1))
    Xs, ys = [], []
    for ex in examples:
        if not ex.valid and ex.contact_valid is not None and not all(ex.contact_valid):
            continue  # rejected for a contact: a point label (tree 1), not a set label
        a = set_attributes_of_example(ex, params, shifts)
        Xs.append(a)
        ys.append(np.full(len(a), ex.valid))
    Xs, ys = np.vstack(Xs), np.concatenate(ys)
    valid = [ex for ex in examples if ex.valid]
    ex_attrs = np.vstack([set_attributes_of_example(ex, params) for ex in valid])
    scale = Xs.std(axis=0)
    scale[scale < 1e-9] = 1.0
    pt = AttributeTree(local_names(params.scales_mm), params.tree_max_depth, params.tree_min_samples_leaf,
                       params.tree_minority_weight_max).fit(Xp, yp)
    st = AttributeTree(global_names(params.scales_mm), params.tree_max_depth, params.tree_min_samples_leaf,
                       params.tree_minority_weight_max).fit(Xs, ys)
    counts = {"examples": len(examples), "valid_examples": len(valid), "point_rows": len(yp),
              "point_rows_valid": int(yp.sum()), "set_rows": len(ys), "set_rows_valid": int(ys.sum())}
    parts = np.vstack([part_attributes(ex.part) for ex in valid])
    part_scale = np.maximum(parts.std(axis=0), PART_SCALE_FLOOR)
    return LearnedModel(pt, st, ex_attrs, [ex.id for ex in valid], scale, counts, parts, part_scale,
                        params.part_shape_weight)


# The part-shape space's normalisation (the accepted examples' standard deviation) is at least this: examples all
# on parts of one kind do not make a part 5 % longer for its width a stranger (ln elongation, solidity)
PART_SCALE_FLOOR = np.array([0.1, 0.05])


NEAREST_ROWS_PER_BLOCK = 32


def part_distances(model: LearnedModel, part_attrs: np.ndarray | None) -> np.ndarray | None:
    """(e,) weighted distance of a part's shape to each accepted example's part (normalised part-shape space),
    None when the choice does not look at the part (part_shape_weight 0)."""
    if model.part_weight <= 0 or part_attrs is None or model.example_parts is None:
        return None
    return model.part_weight * np.linalg.norm((part_attrs - model.example_parts) / model.part_scale, axis=-1)


def nearest_example(model: LearnedModel, G: np.ndarray, part_attrs: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Distance (k,) of each set to its nearest accepted example in the normalised global-attribute
    space (paper Eq. 8), and that example's index (k,). With part_attrs (the target's part_attributes) and a
    part_shape_weight, the space also holds the parts' shape, weighted: the global attributes say how a set
    lies on its part (centred, square to it), not what part it is, so a centred set of a lever matched a
    centred example of a box exactly and a lever taught to be held at an end was held in the middle."""
    # in blocks of rows: one (k, examples, attributes) difference for hundreds of sets is megabytes,
    # fresh memory at every plan (the same values, at half the time)
    E, rows = model.example_attrs, NEAREST_ROWS_PER_BLOCK
    dp = part_distances(model, part_attrs)
    dist, which = np.empty(len(G)), np.empty(len(G), int)
    for a in range(0, len(G), rows):
        d = np.linalg.norm((G[a:a + rows, None, :] - E[None, :, :]) / model.scale, axis=-1)
        if dp is not None:
            d = np.sqrt(d * d + dp * dp)
        dist[a:a + rows], which[a:a + rows] = d.min(axis=1), d.argmin(axis=1)
    return dist, which
