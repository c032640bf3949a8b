"""Recipes as files: every shipped model's recipe loads into the project's config classes, and its
smoke version (two categories, ten shapes each, two steps a stage) runs end to end through the one
command that makes the shipped model, writing a checkpoint that loads; a broken recipe is refused
in one line."""

from __future__ import annotations

import json

import pytest

from model.checkpoint import load_model
from research.recipe import load_recipe, recipe_names
from research.release import main as release_main

SHIPPED = {"image-to-shape": "image", "completion": "completion", "classify": "classify", "foreground": "foreground"}


def test_there_is_a_recipe_for_every_shipped_checkpoint():
    assert recipe_names() == sorted(SHIPPED)
    for name, task in SHIPPED.items():
        recipe = load_recipe(name)
        assert recipe.checkpoint == name and recipe.task == task
        assert all(s.config.get("iters") for s in recipe.stages)


@pytest.mark.parametrize("name", sorted(SHIPPED))
def test_the_smoke_version_of_each_recipe_makes_a_checkpoint(name, tmp_path, capsys):
    out = tmp_path / "checkpoint"
    assert release_main([name, "--workdir", str(tmp_path / "work"), "--smoke", "--out", str(out)]) == 0
    meta = json.loads((out / "model.json").read_text())
    assert meta["task"] == name and meta["recipe"]["file"] == f"research/recipes/{name}.toml"
    assert meta["train_command"] == f"python -m research.release {name} --workdir WORKDIR"
    assert meta["evaluation"]["shapes"] > 0 and meta["steps"] == 2
    assert load_model(out).config.task == SHIPPED[name]
    assert f"{out}: {name}" in capsys.readouterr().out


def test_a_broken_recipe_is_refused_in_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    text = load_recipe("classify").path.read_text()
    for broken, needle in ((text.replace('data = "procedural"\n[stages.config]', 'data = "elsewhere"\n[stages.config]'),
                            "reads dataset elsewhere"),
                           (text.replace("iters = 2000", "iterations = 2000"), "iterations"),
                           ("checkpoint = 3", "not a recipe")):
        bad.write_text(broken)
        assert release_main([str(bad), "--workdir", str(tmp_path / "w")]) == 2
        err = capsys.readouterr().err
        assert needle in err and err.count("\n") == 1
    assert release_main(["nothing", "--workdir", str(tmp_path / "w")]) == 2
    assert "the recipes are classify, completion, foreground, image-to-shape" in capsys.readouterr().err
    assert not (tmp_path / "w").exists()
