"""The ablation driver: the rows switch exactly the paper's components, and the table is
spliced into the document without losing the discussion around it."""

import pytest

from likeness_train.ablation import BEGIN, END, ROWS, splice, table
from likeness_train.evaluate import METRIC_KEYS
from likeness_train.train import config_from_args


def test_rows_add_one_component_each():
    cumulative = ["expression_corrections", "dynamic_albedo", "parsing_loss", "gradient_loss"]
    for k, row in enumerate(ROWS):
        config, _ = config_from_args(["--out", "x", *ROWS[row][1]])
        on = [name for name in cumulative if getattr(config, name)]
        assert on == cumulative[:k], (row, on)


def _results(value):
    return {"metrics": dict.fromkeys(METRIC_KEYS, value), "config": {"stage1_steps": 8, "stage2_steps": 2}, "training_elapsed_s": 120.0}


def test_table_and_splice():
    text = table([("A", "first", _results(0.5)), ("B", "second", _results(0.25))])
    lines = text.splitlines()
    assert len(lines) == 4 and lines[2].startswith("| A | first | 8 + 2 | 2 min |") and "50.00 %" in lines[2]
    doc = splice("", text)
    assert doc.startswith("# Ablation") and BEGIN in doc and END in doc
    edited = doc.replace("# Ablation", "# Ablation\n\nDiscussion above.") + "\nDiscussion below.\n"
    again = splice(edited, table([("A", "first", _results(0.1))]))
    assert "Discussion above." in again and "Discussion below." in again
    assert "| B |" not in again and "0.1000" in again


def test_stored_rows_are_reused_only_for_the_same_budget_and_flags(tmp_path, monkeypatch):
    import json
    from dataclasses import asdict

    import likeness_train.ablation as ablation

    config, _ = config_from_args(["--out", "x", "--stage1-steps", "8", "--stage2-steps", "2", "--landmark-warmup-steps", "5", *ROWS["B"][1]])
    stored = tmp_path / "B.json"
    stored.write_text(json.dumps({"config": asdict(config), "evaluation": {"people": 3}, "metrics": {}}))

    class Trains(Exception):
        pass

    def refuse(args):
        raise Trains(args)

    monkeypatch.setattr(ablation, "_run", refuse)
    assert ablation.train_and_evaluate("B", tmp_path / "runs", [], 3, stored, 8, 2, warmup_steps=5)["evaluation"]["people"] == 3
    # Another budget, warm-up, another row's flags or another evaluation size must train again.
    for row, people, s1, s2, warm in (("B", 3, 9, 2, 5), ("B", 3, 8, 2, 6), ("C", 3, 8, 2, 5), ("B", 4, 8, 2, 5)):
        with pytest.raises(Trains) as trained:
            ablation.train_and_evaluate(row, tmp_path / "runs", [], people, stored, s1, s2, warmup_steps=warm)
        assert "likeness_train.train" in trained.value.args[0]
    # So must another frozen start of stage 1 (the stored row has the default).
    frozen = config.stage1_track_frozen_steps
    assert ablation.train_and_evaluate("B", tmp_path / "runs", [], 3, stored, 8, 2, warmup_steps=5, frozen_steps=frozen)["evaluation"]["people"] == 3
    with pytest.raises(Trains):
        ablation.train_and_evaluate("B", tmp_path / "runs", [], 3, stored, 8, 2, warmup_steps=5, frozen_steps=frozen + 1)


def test_unreadable_results_are_a_clear_error(tmp_path):
    from likeness_train.ablation import main

    bad = tmp_path / "full.json"
    bad.write_text("{not json")
    with pytest.raises(SystemExit, match="cannot read evaluation results"):
        main(["--rows", "", "--full", str(bad), "--out", str(tmp_path / "ablation.md")])
    with pytest.raises(SystemExit, match="cannot read evaluation results"):
        main(["--rows", "", "--full", str(tmp_path / "missing.json"), "--out", str(tmp_path / "ablation.md")])


def test_weight_overrides_change_one_term_and_bad_ones_are_refused(capsys):
    from likeness_train.losses import TRAINING_WEIGHTS

    config, _ = config_from_args(["--out", "x", "--weight", "lm=1.5", "--weight", "pa=0"])
    assert config.weights == {**TRAINING_WEIGHTS, "lm": 1.5, "pa": 0.0}
    for bad in ("xx=1", "lm=abc", "lm=-1", "lm=nan", "lm"):
        with pytest.raises(SystemExit):
            config_from_args(["--out", "x", "--weight", bad])
        assert "--weight" in capsys.readouterr().err


def test_rows_start_from_a_finished_warmup_only(tmp_path):
    import torch

    from likeness_train.ablation import start_from_warmup

    warmup = tmp_path / "warmup.pt"
    torch.save({"stage": 0, "step": 5, "track_net": {}}, warmup)
    start_from_warmup(tmp_path / "A", warmup, 5)
    assert torch.load(tmp_path / "A" / "checkpoint.pt", weights_only=False)["step"] == 5
    # A row that has its own checkpoint keeps it (it resumes where it was).
    torch.save({"stage": 1, "step": 9}, tmp_path / "A" / "checkpoint.pt")
    start_from_warmup(tmp_path / "A", warmup, 5)
    assert torch.load(tmp_path / "A" / "checkpoint.pt", weights_only=False)["step"] == 9
    torch.save({"stage": 1, "step": 5}, warmup)  # saved at the switch, before any stage-1 step
    start_from_warmup(tmp_path / "C", warmup, 5)
    for state in ({"stage": 2, "step": 5}, {"stage": 0, "step": 4}, {"stage": 1, "step": 6}):
        torch.save(state, warmup)
        with pytest.raises(SystemExit, match="not the end of a 5-step warm-up"):
            start_from_warmup(tmp_path / "B", warmup, 5)
    warmup.write_bytes(b"not a checkpoint")
    with pytest.raises(SystemExit, match="cannot read the warm-up checkpoint"):
        start_from_warmup(tmp_path / "B", warmup, 5)
