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

    config, _ = config_from_args(["--out", "x", "--stage1-steps", "8", "--stage2-steps", "2", *ROWS["B"][1]])
    stored = tmp_path / "B.json"
    stored.write_text(json.dumps({"config": asdict(config), "evaluation": {"people": 3}, "metrics": {}}))

    class Trains(Exception):
        pass

    def refuse(args):
        raise Trains(args)

    monkeypatch.setattr(ablation, "_run", refuse)
    assert ablation.train_and_evaluate("B", tmp_path / "runs", [], 3, stored, 8, 2)["evaluation"]["people"] == 3
    # Another budget, another row's flags or another evaluation size must train again.
    for row, people, s1, s2 in (("B", 3, 9, 2), ("C", 3, 8, 2), ("B", 4, 8, 2)):
        with pytest.raises(Trains) as trained:
            ablation.train_and_evaluate(row, tmp_path / "runs", [], people, stored, s1, s2)
        assert "likeness_train.train" in trained.value.args[0]


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
