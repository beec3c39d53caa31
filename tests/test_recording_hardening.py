"""Bad recording directories, damaged recordings and concurrent example appends: each is a
clear error (exit 2), never a traceback, a wrong exit code or a lost or mixed-up file."""


from conftest import run_cli


def test_cell_run_refuses_to_record_into_a_non_empty_directory_and_leaves_it_alone(tmp_path, capsys):
    d = tmp_path / "notes"
    (d / "frames").mkdir(parents=True)
    (d / "decisions.jsonl").write_text('{"type": "mine"}\n')
    (d / "frames" / "000009.png").write_bytes(b"not a recording's frame")
    before = {p: p.read_bytes() for p in d.rglob("*") if p.is_file()}
    code, _, err = run_cli("run", "--record", d, capsys=capsys)
    assert code == 2 and "not empty" in err and "Traceback" not in err
    assert {p: p.read_bytes() for p in d.rglob("*") if p.is_file()} == before


def test_cell_run_record_where_nothing_can_be_written_is_bad_input(tmp_path, capsys):
    f = tmp_path / "a-file"
    f.write_text("x")
    code, _, err = run_cli("run", "--record", f / "session", capsys=capsys)
    assert code == 2 and "cannot write the recording" in err and "Traceback" not in err
    assert f.read_text() == "x"


def _append_same_ids(args):
    import dataclasses

    from cell.errors import BadInput
    from cell.examples import append_examples, load_examples

    path, n = args
    src = load_examples(None)[:3]
    refused = 0
    for i in range(n):
        try:
            append_examples(path, [dataclasses.replace(src[i % 3], id=f"same-{i}")])
        except BadInput as e:
            assert "already in" in str(e)
            refused += 1
    return refused


def test_concurrent_appenders_of_the_same_ids_never_write_a_duplicate(tmp_path):
    """The id check runs under the file's lock: two processes adding the same next id (two
    stations, or a station and a run) add it once, the other is refused; the file stays readable."""
    import multiprocessing

    from cell.examples import load_examples

    path = tmp_path / "examples.jsonl"
    with multiprocessing.get_context("fork").Pool(6) as pool:
        refused = pool.map(_append_same_ids, [(path, 6)] * 6)
    ids = [e.id for e in load_examples(path)]
    assert sorted(ids) == [f"same-{i}" for i in range(6)]
    assert sum(refused) == 6 * 6 - 6

