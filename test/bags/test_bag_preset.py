"""A converted bag carries its folder's config preset, so ``sgs-slam run BAG`` uses the same one."""

import shutil

import pytest
import yaml

from bags import BagError, convert
from bags.cli import main as bag_main
from bags.preset import PRESET_KEY, read_bag_preset
from sgs_slam_core.cli import main as slam_main
from sgs_slam_core.cli.run import default_preset
from sgs_slam_core.datasets import DatasetOptions, open_dataset


def test_convert_stores_the_folder_preset_and_run_uses_it(tiny_scene, tmp_path, capsys):
    bag = tmp_path / "bag"
    assert bag_main(["convert", str(tiny_scene), "--out", str(bag), "--max-frames", "2"]) == 0
    assert "(preset synthetic)" in capsys.readouterr().out
    assert read_bag_preset(bag) == default_preset(tiny_scene, "auto") == default_preset(bag, "auto") == "synthetic"
    quick = ["--set", "tracking.adam.iterations=2", "--set", "mapping.iterations=2", "--quiet"]
    assert slam_main(["run", str(bag), "--out", str(tmp_path / "run"), "--max-frames", "2", *quick]) == 0
    assert "preset synthetic" in capsys.readouterr().err
    assert yaml.safe_load((tmp_path / "run" / "run.yaml").read_text())["preset"] == "synthetic"


def test_a_replica_folder_gives_a_replica_bag_and_foreign_bags_default_to_tum(tiny_scene, tmp_path):
    replica = tmp_path / "replica"
    shutil.copytree(tiny_scene, replica)
    (replica / "synthetic.yaml").unlink()
    assert bag_main(["convert", str(replica), "--out", str(tmp_path / "rbag"), "--max-frames", "1"]) == 0
    assert read_bag_preset(tmp_path / "rbag") == "replica"
    convert(open_dataset(tiny_scene, options=DatasetOptions(max_frames=1)), tmp_path / "plain")  # no preset given
    assert read_bag_preset(tmp_path / "plain") is None and default_preset(tmp_path / "plain", "auto") == "tum"


def test_unknown_presets_are_refused_on_convert_and_on_run(tiny_scene, tmp_path, capsys):
    dataset = open_dataset(tiny_scene, options=DatasetOptions(max_frames=1))
    with pytest.raises(BagError, match="unknown preset 'bogus'"):
        convert(dataset, tmp_path / "x", preset="bogus")
    assert not (tmp_path / "x").exists()
    bag = tmp_path / "bag"
    convert(dataset, bag, preset="synthetic")
    meta = bag / "metadata.yaml"
    meta.write_text(meta.read_text().replace(f"{PRESET_KEY}: synthetic", f"{PRESET_KEY}: from_the_future"))
    assert slam_main(["run", str(bag), "--out", str(tmp_path / "run")]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "preset 'from_the_future'" in err and "--preset" in err
