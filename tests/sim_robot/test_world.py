"""World files: shipped worlds, presets, and each invalid world rejected with its reason."""

import math

import numpy as np
import pytest

from sim_robot import (
    PRESETS,
    Arena,
    ArenaShape,
    World,
    WorldError,
    load_world,
    preset,
    world_from_dict,
)


def test_paper_world_is_the_figure_7a_setup(worlds_dir):
    world = load_world(worlds_dir / "paper.toml")
    assert world.arena.shape == "circle"
    assert sorted(ob.shape for ob in world.obstacles) == ["circle", "square", "triangle"]
    assert not world.obstacles_solid and not world.walls_solid
    b = world.body
    assert b.n_sensors == 7
    np.testing.assert_allclose(np.rad2deg(b.sensor_angles_rad), [-90, -60, -30, 0, 30, 60, 90])
    assert 0.2 <= b.max_range_m <= 0.3 and 0.5 <= world.arena.radius_m <= 1.0
    assert world.noise_sd_m == 0.0


def test_bench_world_extends_the_paper_world_with_16_sensors(worlds_dir):
    paper = load_world(worlds_dir / "paper.toml")
    bench = load_world(worlds_dir / "bench16.toml")
    assert bench.body.n_sensors == 16
    assert bench.arena == paper.arena and len(bench.obstacles) == 3
    np.testing.assert_array_equal(bench.obstacles[0].vertices_m, paper.obstacles[0].vertices_m)


def test_every_shipped_world_loads(worlds_dir):
    for path in sorted(worlds_dir.glob("*.toml")):
        Arena.from_toml(path).read_sensors()


def test_khepera_presets():
    k2 = preset("khepera2")
    assert k2.n_sensors == 8 and k2.radius_m == 0.035 and k2.ir_model == "khepera2"
    np.testing.assert_allclose(
        np.rad2deg(k2.sensor_angles_rad), [90, 45, 0, 0, -45, -90, 180, 180], atol=1e-5
    )
    np.testing.assert_allclose(k2.sensor_offsets_m[0], [0.010, 0.024])
    assert k2.max_wheel_mps == pytest.approx(1.016)
    k4 = preset("khepera4")
    assert k4.n_sensors == 8 and k4.wheel_base_m == 0.1054
    np.testing.assert_allclose(np.hypot(*k4.sensor_offsets_m.T), 0.0704)
    k3 = preset("khepera3")
    assert k3.n_sensors == 9 and k3.wheel_base_m == 0.0885 and k3.max_range_m == 0.2
    # back left, left 90, left 45, front left, front right, ..., back: as N reports them
    facings = np.rad2deg(k3.sensor_angles_rad)
    np.testing.assert_allclose(facings[[0, 8]], [129.2, 180.0], atol=0.1)
    np.testing.assert_allclose(facings[:4], -facings[4:8][::-1])  # left-right symmetric
    assert k3.max_wheel_mps == pytest.approx(43_000 / 144.01 / 1000)
    assert set(PRESETS) == {"khepera2", "khepera3", "khepera4", "paper7"}


def test_custom_robot_with_user_sensors(base_world):
    data = base_world()
    data["robot"] = {
        "sensor_angles_deg": [10.0, -170.0, 95.0],
        "max_range_m": 0.4,
        "radius_m": 0.05,
        "wheel_base_m": 0.09,
        "max_wheel_mps": 0.3,
    }
    b = world_from_dict(data).body
    np.testing.assert_allclose(b.sensor_angles_rad, np.radians([10, -170, 95]), atol=1e-6)
    np.testing.assert_allclose(np.hypot(*b.sensor_offsets_m.T), 0.05)  # on the rim
    assert (b.max_range_m, b.wheel_base_m, b.max_wheel_mps) == (0.4, 0.09, 0.3)


def test_placed_and_rotated_obstacles(base_world):
    world = world_from_dict(
        base_world(
            obstacles=[
                {"shape": "square", "center_m": [0.3, 0.2], "side_m": 0.2, "rotation_deg": 45},
                {"shape": "triangle", "center_m": [-0.3, 0.0], "side_m": 0.3},
            ]
        )
    )
    sq, tri = world.obstacles
    # a square rotated 45 deg has its corners on the axes through its centre
    np.testing.assert_allclose(np.abs(sq.vertices_m - [0.3, 0.2]).max(), 0.1 * math.sqrt(2))
    np.testing.assert_allclose(sq.vertices_m.mean(axis=0), [0.3, 0.2], atol=1e-12)
    sides = np.hypot(*(np.roll(tri.vertices_m, -1, axis=0) - tri.vertices_m).T)
    np.testing.assert_allclose(sides, 0.3)


@pytest.mark.parametrize(
    "change, message",
    [
        (
            {"obstacles": [{"shape": "circle", "center_m": [0.9, 0], "radius_m": 0.2}]},
            r"obstacles\[0\] \(circle\) lies partly outside the arena",
        ),
        (
            {"obstacles": [{"shape": "square", "center_m": [0.0, 0.95], "side_m": 0.2}]},
            r"obstacles\[0\] \(square\) lies partly outside the arena",
        ),
        (
            {
                "obstacles": [
                    {
                        "shape": "polygon",
                        "center_m": [0.5, 0.0],
                        "vertices_m": [[0, 0], [0.2, 0.2], [0.2, 0], [0, 0.2]],
                    }
                ]
            },
            r"obstacles\[0\]\.vertices_m is a self-intersecting polygon",
        ),
        (
            {"obstacles": [{"shape": "circle", "center_m": [0.05, 0.0], "radius_m": 0.1}]},
            r"robot\.start .* obstacles\[0\] \(circle\)",
        ),
        (
            {"obstacles": [{"shape": "square", "center_m": [0.5, 0.0], "side_m": -1}]},
            r"obstacles\[0\]\.side_m must be a finite number > 0, got -1",
        ),
        (
            {"obstacles": [{"shape": "circle", "center_m": [0.5, 0.0], "radius_m": 0}]},
            r"obstacles\[0\]\.radius_m must be a finite number > 0",
        ),
        ({"arena": {"shape": "circle", "radius_m": -1}}, r"arena\.radius_m must be .* > 0"),
        (
            {"arena": {"shape": "rectangle", "width_m": 1.0, "height_m": 0}},
            r"arena\.height_m must be .* > 0",
        ),
        ({"arena": {"shape": "hexagon", "radius_m": 1}}, r"arena\.shape must be one of"),
        ({"physics": {"obstacles": "sticky"}}, r"physics\.obstacles must be one of"),
        ({"sensors": {"noise_sd_m": -0.1}}, r"sensors\.noise_sd_m must be >= 0"),
        ({"obstacles": [{"shape": "blob"}]}, r"obstacles\[0\]\.shape must be one of"),
        (
            {"obstacles": [{"shape": "square", "center_m": [0.5, 0]}]},
            r"obstacles\[0\]\.side_m is missing",
        ),
        (
            {"obstacles": [{"shape": "circle", "radius_m": 0.1, "colour": "red"}]},
            r"obstacles\[0\]\.colour is not a known key",
        ),
        (
            {
                "obstacles": [
                    {
                        "shape": "polygon",
                        "vertices_m": [[0, 0], [0.1, 0.1], [0.2, 0.2]],
                        "center_m": [0.5, 0.0],
                    }
                ]
            },
            r"obstacles\[0\] \(polygon\) has zero area",
        ),
    ],
)
def test_invalid_worlds_are_rejected_with_their_reason(base_world, change, message):
    with pytest.raises(WorldError, match=message):
        world_from_dict(base_world(**change))


@pytest.mark.parametrize(
    "robot, message",
    [
        ({"max_range_m": -0.2}, r"robot\.max_range_m must be a finite number > 0"),
        ({"radius_m": 0}, r"robot\.radius_m must be a finite number > 0"),
        ({"wheel_base_m": -0.05}, r"robot\.wheel_base_m must be a finite number > 0"),
        ({"max_wheel_mps": 0}, r"robot\.max_wheel_mps must be a finite number > 0"),
        ({"sensor_angles_deg": []}, r"robot\.sensor_angles_deg must list at least one sensor"),
        ({"preset": "roomba"}, r"robot\.preset must be one of"),
        ({"ir_model": "sharp"}, r"robot\.ir_model must be one of"),
        ({"sensor_offsets_m": [[0, 0]]}, r"robot\.sensor_offsets_m must be 5 finite"),
        ({"start": {"x_m": 0.99}}, r"robot\.start .* outside or across the arena wall"),
        ({"start": {"x_m": 5.0}}, r"robot\.start .* outside or across the arena wall"),
        ({"wheels": 2}, r"robot\.wheels is not a known key"),
    ],
)
def test_invalid_robots_are_rejected_with_their_reason(base_world, robot, message):
    data = base_world()
    data["robot"].update(robot)
    with pytest.raises(WorldError, match=message):
        world_from_dict(data)


def test_world_error_is_a_value_error():
    assert issubclass(WorldError, ValueError)


def test_missing_file_and_bad_toml(tmp_path):
    with pytest.raises(WorldError, match="not found"):
        load_world(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[arena\nradius_m = 1")
    with pytest.raises(WorldError, match="not valid TOML"):
        load_world(bad)


def test_extends_merges_tables_and_replaces_obstacles(tmp_path, worlds_dir):
    child = tmp_path / "child.toml"
    child.write_text(
        f'extends = "{(worlds_dir / "paper.toml").as_posix()}"\n'
        "[arena]\nradius_m = 0.8\n"
        '[[obstacles]]\nshape = "circle"\ncenter_m = [0.5, 0.0]\nradius_m = 0.1\n'
    )
    world = load_world(child)
    assert world.arena.radius_m == 0.8 and world.arena.shape == "circle"
    assert [ob.shape for ob in world.obstacles] == ["circle"]
    assert world.body.n_sensors == 7  # robot table inherited


def test_world_can_be_built_in_python():
    world = World(
        name="py",
        arena=ArenaShape("rectangle", width_m=2.0, height_m=1.0),
        obstacles=(),
        body=preset("paper7"),
    )
    assert Arena(world).read_sensors().shape == (7,)


def test_a_world_error_is_a_config_error():
    from settings import ConfigError

    assert issubclass(WorldError, ConfigError)


def test_an_empty_or_binary_world_file_is_named(tmp_path):
    (tmp_path / "empty.toml").write_text("")
    with pytest.raises(WorldError, match="world file .*empty.toml is empty"):
        load_world(tmp_path / "empty.toml")
    (tmp_path / "w.png").write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00")
    with pytest.raises(WorldError, match="not a text file"):
        load_world(tmp_path / "w.png")


def test_extends_is_relative_to_the_extending_file(tmp_path, worlds_dir, monkeypatch):
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "big.toml").write_text(
        f'extends = "{worlds_dir.as_posix()}/paper.toml"\n[arena]\nradius_m = 0.9\n'
    )
    (tmp_path / "mine" / "bigger.toml").write_text('extends = "big.toml"\nname = "bigger"\n')
    monkeypatch.chdir(tmp_path)
    world = load_world("mine/bigger.toml", ["arena.radius_m=1.1"])
    assert world.name == "bigger" and world.arena.radius_m == 1.1
    assert len(world.obstacles) == 3


def test_a_world_extending_the_papers_may_make_its_arena_a_rectangle(tmp_path):
    """`extends` merged the arena key by key: the paper's radius_m stayed, and a rectangle
    was refused for a key the user never wrote."""
    from pathlib import Path

    from sim_robot.world import load_world

    paper = Path("configs/worlds/paper.toml").resolve()
    mine = tmp_path / "box.toml"
    mine.write_text(
        f'extends = "{paper}"\n[arena]\nshape = "rectangle"\nwidth_m = 1.2\nheight_m = 1.0\n'
    )
    world = load_world(mine)
    assert world.arena.shape == "rectangle"
    assert (world.arena.width_m, world.arena.height_m) == (1.2, 1.0)
