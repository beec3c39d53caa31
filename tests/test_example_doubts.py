"""Example files that are read but doubtful: the same grasp on two lines (a changed mind, a grasp taught
twice) and a configuration whose jaws are not along the contacts' line. Each is named in a warning on
stderr (both lines, or the line), the file is still read, and a configuration that is not the grasp's
is not used by step 5. The shipped example files give no warning."""

import json
from dataclasses import replace

import numpy as np
import pytest
from conftest import ROOT, run_cli
from test_files import _example

from cell.configuration import example_configurations
from cell.examples import MAX_WARNINGS, append_examples, default_examples_path, load_examples
from cell.kinematics import Joints


def _file(tmp_path, examples):
    path = tmp_path / "ex.jsonl"
    append_examples(path, examples)
    return path


def _warnings(path):
    got = []
    load_examples(path, warn=got.append)
    return got


@pytest.mark.parametrize("path", [default_examples_path(), ROOT / "recordings" / "shipped" / "examples_at_start.jsonl"])
def test_the_shipped_example_files_give_no_warning(path):
    assert _warnings(path) == []
    assert len(example_configurations(load_examples(path))) == 60  # every accepted grasp's configuration is used


def test_the_same_grasp_accepted_and_rejected_is_named_on_both_lines_and_both_count(tmp_path, capsys):
    other = replace(_example("c"), contacts_mm=np.array([[300.0, 30.0], [340.0, 30.0]]))  # another grasp
    # the rejection's contacts in the other order and 0.8 mm off: still the same grasp
    rejected = replace(_example("b", valid=False), contacts_mm=np.array([[340.0, 20.8], [300.0, 20.0]]))
    path = _file(tmp_path, [_example("a"), other, rejected])
    assert _warnings(path) == [
        f"example file {path} lines 1 (a) and 3 (b): the same grasp of part 'sq' (contacts within 1 mm), accepted "
        "on line 1 and rejected on line 3: both count (the later line does not replace the earlier), the trees "
        "learn both verdicts; remove the line you no longer mean"]
    assert [e.id for e in load_examples(path)] == ["a", "c", "b"]  # read, all three
    code, out, err = run_cli("rules", "--examples", path, capsys=capsys)
    assert code == 0 and "Learned from 3 examples (2 accepted)" in out
    assert err.startswith(f"cell: warning: example file {path} lines 1 (a) and 3 (b): ") and err.count("\n") == 1


def test_a_per_contact_verdict_follows_its_contact_when_the_other_line_lists_them_the_other_way(tmp_path):
    a = replace(_example("a", valid=False), contact_valid=(True, False))
    b = replace(_example("b", valid=False), contact_valid=(False, True), contacts_mm=a.contacts_mm[::-1].copy())
    c = replace(_example("c", valid=False), contact_valid=(False, True))
    [ab, ac, bc] = _warnings(_file(tmp_path, [a, b, c]))
    assert "lines 1 (a) and 2 (b)" in ab and "rejected (contacts good, bad) twice under two ids" in ab
    assert ("lines 1 (a) and 3 (c)" in ac
            and "rejected (contacts good, bad) on line 1 and rejected (contacts bad, good) on line 3" in ac)
    assert "lines 2 (b) and 3 (c)" in bc and "rejected (contacts bad, good) on line 2 and" in bc


def test_a_grasp_taught_twice_under_two_ids_is_named_and_weighs_twice(tmp_path):
    path = _file(tmp_path, [_example("a"), _example("a-again")])
    assert _warnings(path) == [
        f"example file {path} lines 1 (a) and 2 (a-again): the same grasp of part 'sq' (contacts within 1 mm), "
        "accepted twice under two ids: both count, it weighs twice in the trees"]
    assert len(load_examples(path)) == 2


@pytest.mark.parametrize("change", [
    {"contacts_mm": np.array([[300.0, 21.1], [340.0, 20.0]])},  # a contact 1.1 mm away
    {"part": replace(_example("x").part, id="sq2")},  # another part id
])
def test_another_grasp_or_another_part_is_not_the_same_grasp(tmp_path, change):
    assert _warnings(_file(tmp_path, [_example("a"), replace(_example("b", valid=False), **change)])) == []


def test_the_same_part_id_moved_is_another_part(tmp_path):
    from cell.scene import parse_part

    moved = parse_part({"id": "sq", "outline": [[300, 1.5], [340, 1.5], [340, 41.5], [300, 41.5]], "z_top": 10})
    b = replace(_example("b", valid=False), part=moved, contacts_mm=np.array([[300.0, 20.5], [340.0, 20.5]]))
    assert _warnings(_file(tmp_path, [_example("a"), b])) == []  # outlines 1.5 mm apart: not the same part


def _with_jaws_at(eid, axis_deg):
    """Example `eid` on the square (contacts along 0 deg, 1.5 mm apart from eid to eid: other grasps) with a
    configuration closing along `axis_deg`."""
    y_mm = 1.0 + 1.5 * int(eid[1:])
    return replace(_example(eid), contacts_mm=np.array([[300.0, y_mm], [340.0, y_mm]]),
                   joints=Joints(30.0, 100.0, 5.0, axis_deg - 130.0 + 180.0))


def test_a_configuration_whose_jaws_are_off_the_contacts_line_is_named_and_not_used_by_step_5(tmp_path):
    path = _file(tmp_path, [_with_jaws_at("e1", 4.9), _with_jaws_at("e2", -5.1), _with_jaws_at("e3", 60.0)])
    assert _warnings(path) == [
        f"example file {path} line 2 (e2): 'joints' close the jaws along -5.1 deg (J1 + J2 + J4), 5.1 deg off "
        "the contacts' line (at most 5): not this grasp's configuration; step 5 does not use it",
        f"example file {path} line 3 (e3): 'joints' close the jaws along 60.0 deg (J1 + J2 + J4), 60.0 deg off "
        "the contacts' line (at most 5): not this grasp's configuration; step 5 does not use it"]
    got = load_examples(path)
    assert [e.joints is not None for e in got] == [True, False, False]
    assert np.allclose(example_configurations(got), [[30.0, 100.0, 5.0, 54.9]])  # e1's only
    # the line is kept as written: what the file says is what an append or a copy writes back
    assert got[2].to_json()["joints"] == {"j1_deg": 30.0, "j2_deg": 100.0, "j3_mm": 5.0, "j4_deg": 110.0}
    assert [json.loads(line) for line in path.read_text().splitlines()] == [e.to_json() for e in got]


def test_warnings_past_the_limit_are_counted_not_listed(tmp_path):
    path = _file(tmp_path, [_with_jaws_at(f"e{k}", 45.0) for k in range(MAX_WARNINGS + 5)])
    got = _warnings(path)
    assert len(got) == MAX_WARNINGS + 1 and got[-1] == f"example file {path}: 5 more doubtful lines like these " \
                                                       "(not listed)"


def test_a_file_read_without_warn_is_read_silently(tmp_path, capsys):
    load_examples(_file(tmp_path, [_example("a"), _example("b", valid=False)]))
    assert capsys.readouterr().err == ""
