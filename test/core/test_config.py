from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import pytest

from sgs_slam_core.config import SlamConfig, build, config_to_dict, dump_yaml, list_presets, load_config
from sgs_slam_core.config.loader import load_yaml, parse_override
from sgs_slam_core.errors import ConfigError
from sgs_slam_core.render import RenderSettings


@dataclass(frozen=True)
class Inner:
    rate: float = 1.0
    name: Literal["a", "b"] = "a"
    sizes: tuple[int, int] = (1, 2)


@dataclass(frozen=True)
class Outer:
    inner: Inner = field(default_factory=Inner)
    count: int = 3
    flag: bool = False
    note: str | None = None


def test_build_nested_and_types():
    cfg = build(Outer, {"inner": {"rate": 2, "sizes": [3, 4]}, "flag": True})
    assert cfg.inner.rate == 2.0 and isinstance(cfg.inner.rate, float)
    assert cfg.inner.sizes == (3, 4) and cfg.flag is True and cfg.count == 3
    assert config_to_dict(cfg)["inner"]["sizes"] == [3, 4]


@pytest.mark.parametrize(
    ("data", "match"),
    [
        ({"inner": {"rat": 1}}, "unknown config key inner.rat"),
        ({"bogus": 1}, "unknown config key bogus"),
        ({"count": 1.5}, "count: expected an integer"),
        ({"flag": 1}, "flag: expected true/false"),
        ({"inner": {"name": "c"}}, r"inner.name: must be one of \['a', 'b'\]"),
        ({"inner": {"sizes": [1]}}, "expected 2 values"),
        ({"inner": 3}, "expected a mapping"),
    ],
)
def test_build_rejects_bad_input(data, match):
    with pytest.raises(ConfigError, match=match):
        build(Outer, data)


def test_presets_load_and_overrides_apply(tmp_path):
    assert {"replica", "scannet", "tum", "synthetic"} <= set(list_presets())
    for name in list_presets():
        assert isinstance(load_config(name), SlamConfig)
    path = tmp_path / "c.yaml"
    path.write_text("render:\n  backend: torch\n")
    cfg = load_config("scannet", path, ["mapping.lr_means=0.5", "seed=7"])
    assert cfg.render.backend == "torch" and cfg.mapping.lr_means == 0.5 and cfg.seed == 7
    assert load_config(overrides=["mapping.lr_means=1e-3"]).mapping.lr_means == 0.001  # YAML 1.1: 1e-3 is text
    dump_yaml(cfg, tmp_path / "out.yaml")
    assert load_config(path=tmp_path / "out.yaml") == cfg


def test_range_errors_and_bad_overrides(tmp_path):
    with pytest.raises(ConfigError, match="backend"):
        load_config(overrides=["render.backend=opengl"])
    unknown = r"unknown config key render\.tile_size \(known at this level: backend, compile\)"
    with pytest.raises(ConfigError, match=unknown):
        load_config(overrides=["render.tile_size=16"])  # the renderer's constants are no config keys
    with pytest.raises(ConfigError, match="tile_size"):
        RenderSettings(tile_size=0)  # code that builds the settings still has them checked
    with pytest.raises(ConfigError, match="unknown preset 'nope'"):
        load_config("nope")
    with pytest.raises(ConfigError, match="section\\.key=value"):
        parse_override("justakey")
    bad = tmp_path / "bad.yaml"
    bad.write_text("- a list\n")
    with pytest.raises(ConfigError, match="mapping at the top level"):
        load_yaml(bad)
    with pytest.raises(ConfigError, match="cannot read"):
        load_yaml(tmp_path / "missing.yaml")


def test_live_runs_swap_in_the_live_tracker_and_lockstep_runs_keep_the_presets():
    preset = load_config("replica")
    assert preset.tracking.method == "adam" and preset.for_live().tracking.method == "gauss_newton"
    assert preset.for_live().tracking.adam == preset.tracking.adam  # the rest of the section stays
    keep = load_config("replica", overrides=["live.overlay.tracking.method=adam"])
    assert keep.for_live().tracking == keep.tracking
    for name in ("tum", "synthetic"):  # Gauss-Newton in lockstep as well: nothing to swap
        config = load_config(name)
        assert config.tracking.method == "gauss_newton" and config.for_live().tracking == config.tracking
    with pytest.raises(ConfigError, match=r"live\.overlay\.tracking\.method"):
        load_config("tum", overrides=["live.overlay.tracking.method=lbfgs"])


def test_the_live_overlay_takes_any_key_of_any_section_and_merges_into_its_default():
    config = load_config("synthetic", overrides=["live.overlay.mapping.every=5", "live.overlay.guard.lost_after=7"])
    live = config.for_live()
    assert (config.mapping.every, live.mapping.every) == (1, 5) and live.guard.lost_after == 7
    assert live.mapping.iterations == config.mapping.iterations  # the rest of the section stays
    assert live.tracking.method == "gauss_newton" and live.mapping.refresh_labels_keyframes_only  # defaults kept
    assert not config.mapping.refresh_labels_keyframes_only
    for bad, where in (
        ("live.overlay.mapping.every=0", r"live\.overlay\.mapping"),
        ("live.overlay.mapping.no_such_key=1", r"live\.overlay\.mapping\.no_such_key"),
        ("live.overlay.no_such_section.key=1", r"live\.overlay\.no_such_section"),
        ("live.overlay.seed=3", r"live\.overlay\.seed"),
        ("live.overlay.live.min_map_steps=1", r"live\.overlay\.live"),
    ):
        with pytest.raises(ConfigError, match=where):
            load_config("synthetic", overrides=[bad])


def test_live_runs_move_the_maps_geometry_further_per_step():
    config = load_config("tum")  # the preset's scale
    live, lockstep = config.for_live().mapping, config.mapping
    assert live.lr_means == pytest.approx(3 * lockstep.lr_means)
    assert live.lr_scales == pytest.approx(3 * lockstep.lr_scales)
    assert (live.lr_colors, live.lr_opacities, live.iterations) == (
        lockstep.lr_colors,
        lockstep.lr_opacities,
        lockstep.iterations,
    )
    same = load_config("tum", overrides=["live.geometry_lr_scale=1"])
    assert (same.for_live().mapping.lr_means, same.for_live().mapping.lr_scales) == (
        same.mapping.lr_means,
        same.mapping.lr_scales,
    )
    synthetic = load_config("synthetic")
    assert synthetic.for_live().mapping.lr_means == synthetic.mapping.lr_means  # 1 by default
    for bad in ("0", "-1"):
        with pytest.raises(ConfigError, match=r"live\.geometry_lr_scale"):
            load_config("tum", overrides=[f"live.geometry_lr_scale={bad}"])


def test_live_runs_spend_their_few_mapping_steps_on_depth():
    config = load_config("tum")  # the preset's live weights
    live = config.for_live()
    assert (config.mapping.weight_color, live.mapping.weight_color) == (0.5, 0.25)
    assert (config.densify.depth_error_factor, live.densify.depth_error_factor) == (50.0, 20.0)
    assert live.mapping.weight_depth == config.mapping.weight_depth
    assert live.densify == replace(config.densify, depth_error_factor=20.0)  # nothing else of densify
    synthetic = load_config("synthetic")  # not in the default overlay: lockstep's
    assert synthetic.for_live().densify == synthetic.densify
    assert synthetic.for_live().mapping.weight_color == synthetic.mapping.weight_color
    for bad in ("live.overlay.mapping.weight_color=-0.1", "live.overlay.densify.depth_error_factor=0"):
        with pytest.raises(ConfigError, match=r"live\.overlay\."):
            load_config("tum", overrides=[bad])


def test_the_configuration_reference_is_generated_from_the_schema_and_names_every_key():
    from sgs_slam_core.config.reference import config_keys, config_reference

    undocumented = [key for key, _, doc in config_keys() if not doc.strip()]
    assert not undocumented, f"keys without a description in their section's Attributes: {undocumented}"
    doc = (Path(__file__).resolve().parents[2] / "docs" / "config.md").read_text()
    assert doc == config_reference(), "stale: run python -m sgs_slam_core.config.reference > docs/config.md"


def test_a_saved_config_of_an_earlier_version_loads_without_its_retired_keys():
    from sgs_slam_core.config.loader import known_keys

    saved = config_to_dict(load_config("tum"))
    saved["render"]["tile_size"] = 16  # keys an earlier version wrote into its maps
    saved["tracking"]["adam"]["stop_patience"] = 5
    with pytest.raises(ConfigError, match="unknown config key"):
        build(SlamConfig, saved)
    assert build(SlamConfig, known_keys(SlamConfig, saved)) == load_config("tum")
