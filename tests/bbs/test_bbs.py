"""BringBackShapes environment: spec constants, physics, scoring, options, determinism, pixels."""

import functools
import hashlib
import math
import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium
import numpy as np
import pytest

import bbs
from bbs.discovery import DiscoveryTracker
from bbs.geometry import AGENT_RADIUS, DISTRACTOR_VERTICES, OBJECT_SHAPES, arena_geometry
from bbs.layout import parse_layout, sample_layout
from bbs.physics import DAMPING_PER_STEP, DT, Simulation
from bbs.render import VIEW_PALETTE, original_pipeline_view, view_box, view_colour

RIGHT = np.array([-1.0, 1.0], np.float32)  # normalised: angle 0 (towards the goal), force 400
SQUARE_COLOURS = ("orange", "blue", "green", "red", "purple")
REPO_ROOT = Path(__file__).resolve().parents[2]


def square(x, y, colour="red", shape="square", angle=0.0):
    return {"position": (x, y), "angle": angle, "shape": shape, "colour": colour}


def layout(agent=(300.0, 350.0), objects=(), distractors=(), goal_y=None, agent_angle=0.0):
    return {"agent": {"position": agent, "angle": agent_angle}, "objects": list(objects),
            "distractors": [{"position": d} for d in distractors], "goal_y": goal_y}


def simulation(spec, scale=1.0, odd_force_point=True):
    geometry = arena_geometry(scale)
    return Simulation(geometry, parse_layout(spec, geometry), odd_force_point)


def digest(arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


# ------------------------------------------------------------------------------------ spec
@pytest.mark.parametrize("scale, expected", [
    (1.0, (800, 700, 575, 237.5, 225.0)),
    (1.4, (1120, 979, 895, 307.25, 364.5)),
])
def test_arena_geometry_matches_spec(scale, expected):
    g = arena_geometry(scale)
    assert (g.width, g.length, g.goal_x, g.goal_y, g.goal_height) == expected
    gbh = (g.length - g.goal_height - 250) / 2
    left, right, top, bottom, goal_top, goal_bottom = g.walls
    assert (left.x1, right.x0, top.y1, bottom.y0) == (125, g.width - 125, 125, g.length - 125)
    assert (goal_top.x0, goal_top.x1, goal_top.y0, goal_top.y1) == (g.goal_x, g.width - 125, 125,
                                                                    125 + gbh)
    assert (goal_bottom.y0, goal_bottom.y1) == (g.length - 125 - gbh, g.length - 125)
    assert g.score_x == g.goal_x + 5


def test_effective_masses_and_space_settings():
    sim = simulation(layout(objects=[square(200, 200)], distractors=[(400, 400)]))
    assert sim.agent.mass == pytest.approx(70.686, abs=1e-3)
    assert sim.agent.moment == pytest.approx(7952.16, abs=1e-2)
    kite = sim.distractors[0].body
    assert kite.mass == pytest.approx(60.0) and kite.moment == pytest.approx(6583.33, abs=1e-2)
    assert tuple(kite.center_of_gravity) == pytest.approx((-20 / 3, 0.0))
    obj = sim.object_bodies[0]
    assert (obj.mass, obj.moment) == (20.0, 1e6)
    assert sim.space.damping == 0.7 and sim.space.iterations == 10
    assert DAMPING_PER_STEP == pytest.approx(0.994073, abs=1e-6)


def test_default_episode_lasts_751_agent_steps():
    env = bbs.BringBackShapesEnv()
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    steps, truncated, terminated = 0, False, False
    while not (truncated or terminated):
        _, _, terminated, truncated, info = env.step(rng.uniform(-1, 1, 2))
        steps += 1
    assert (steps, truncated, terminated, info["sub_steps"]) == (751, True, False, 3002)
    assert info["discovery"]["episode_length"] == 751


@pytest.mark.parametrize("time_limit, repeat, steps", [(10, 4, 3), (9, 4, 3), (0, 1, 2), (5, 3, 3)])
def test_time_limit_counts_sub_steps_like_the_original(time_limit, repeat, steps):
    env = bbs.BringBackShapesEnv(time_limit=time_limit, action_repeat=repeat)
    env.reset(seed=1)
    for i in range(steps):
        _, _, _, truncated, info = env.step(RIGHT)
        assert truncated == (i == steps - 1)
    assert info["sub_steps"] == time_limit + 2


# ------------------------------------------------------------------------------------ physics
def test_force_is_100_applications_in_closed_form():
    sim = simulation(layout(agent=(200.0, 500.0), objects=[square(400, 200)]))
    sim.control_and_score(0.0, 400.0, np.random.default_rng(0))
    sim.advance()
    force_total, torque_total = 100 * 400.0, 100 * (500.0 - 200.0) * 400.0
    assert sim.agent.velocity.x == pytest.approx(force_total / sim.agent.mass * DT, rel=1e-9)
    assert sim.agent.angular_velocity == pytest.approx(torque_total / sim.agent.moment * DT,
                                                       rel=1e-9)
    centred = simulation(layout(agent=(200.0, 500.0), objects=[square(400, 200)]),
                         odd_force_point=False)
    centred.control_and_score(0.0, 400.0, np.random.default_rng(0))
    centred.advance()
    assert centred.agent.angular_velocity == 0.0
    assert centred.agent.velocity.x == sim.agent.velocity.x


def test_goal_clamp_torque_and_velocity_flip():
    sim = simulation(layout(agent=(300.0, 350.0), objects=[square(200, 200)]))
    sim.agent.position, sim.agent.velocity = (570.0, 350.0), (100.0, 40.0)
    sim.control_and_score(0.0, 400.0, np.random.default_rng(0))
    assert tuple(sim.agent.position) == (560.0, 350.0)
    assert tuple(sim.agent.velocity) == pytest.approx((-30.0, -12.0))
    expected_torque = 400.0 * ((350.0 - 570.0) + 99 * (350.0 - 560.0))
    assert sim.agent.torque == pytest.approx(expected_torque)


def test_speed_under_full_force_matches_measurements():
    env = bbs.BringBackShapesEnv()
    env.reset(options={"layout": layout(agent=(150.0, 350.0), objects=[square(200, 150)])})
    speeds = []
    for _ in range(4):
        env.step(RIGHT)
        speeds.append(env.true_state()["agent_velocity"][0])
    assert speeds == pytest.approx([37, 74, 110, 144], abs=1.5)


def test_soft_velocity_cap_applies_to_fast_objects_only():
    sim = simulation(layout(agent=(150.0, 150.0), objects=[square(200, 300), square(200, 450)]))
    fast, slow = sim.object_bodies
    fast.velocity, slow.velocity = (900.0, 0.0), (800.0, 0.0)
    sim.advance()
    assert fast.velocity.x == pytest.approx(900.0 * DAMPING_PER_STEP * 0.99, rel=1e-12)
    assert slow.velocity.x == pytest.approx(800.0 * DAMPING_PER_STEP, rel=1e-12)
    fast.velocity = (700.0, 0.0)  # the cap is removed again once an object is slow
    sim.advance()
    assert fast.velocity.x == pytest.approx(700.0 * DAMPING_PER_STEP, rel=1e-12)


@pytest.mark.parametrize("goal_y", [None, 130.0, 345.0])
def test_scoring_pushes_reward_and_terminates(goal_y):
    env = bbs.BringBackShapesEnv(time_limit=400)
    opening = arena_geometry(1.0, goal_y)
    mid = opening.goal_y + opening.goal_height / 2
    scene = layout(agent=(500.0, mid), objects=[square(535, mid - 25)], goal_y=goal_y)
    env.reset(seed=0, options={"layout": scene})
    rewards, terminated, truncated = [], False, False
    while not (terminated or truncated):
        _, reward, terminated, truncated, info = env.step(RIGHT)
        rewards.append(reward)
    assert terminated and not truncated
    assert rewards[-1] == 1.0 and sum(rewards) == 1.0
    state = env.true_state()
    assert state["object_scored"].tolist() == [True]
    assert state["object_poses"][0, 0] >= opening.goal_x + 5
    assert info["scored"] == 1 and info["discovery"]["scored"] == 1


def test_agent_cannot_pass_the_goal_line():
    env = bbs.BringBackShapesEnv(time_limit=None)
    env.reset(options={"layout": layout(agent=(400.0, 350.0), objects=[square(200, 150)])})
    true_x = []
    for _ in range(120):
        env.step(RIGHT)
        assert env.scene.agent.x <= 560.0  # drawn (post-clamp) position
        true_x.append(env.true_state()["agent_pose"][0])
    assert max(true_x) < 563.0 and max(true_x) > 555.0


def test_spawn_past_the_goal_line_is_clamped_at_reset():
    env = bbs.BringBackShapesEnv()
    env.reset(options={"layout": layout(agent=(640.0, 200.0), objects=[square(200, 150)],
                                        distractors=[(650.0, 500.0)])})
    state = env.true_state()
    assert state["agent_pose"][0] == 560.0 and state["distractor_poses"][0, 0] == 563.0


def test_nothing_escapes_under_long_random_play_with_distractors():
    for seed, scale in [(0, 1.0), (1, 1.4)]:
        env = bbs.BringBackShapesEnv(num_distractors=4, arena_scale=scale, time_limit=None)
        env.reset(seed=seed)
        width, length = env.geometry.width, env.geometry.length
        rng = np.random.default_rng(seed)
        for _ in range(900):
            env.step(rng.uniform(-1, 1, 2))
            s = env.true_state()
            alive = s["object_poses"][~s["object_scored"]]
            assert np.all((alive[:, 0] > 50) & (alive[:, 0] < width - 50))
            assert np.all((alive[:, 1] > 50) & (alive[:, 1] < length - 50))
            for poses in (s["agent_pose"][None], s["distractor_poses"]):
                assert np.all((poses[:, 0] > 110) & (poses[:, 0] < env.geometry.goal_x))
                assert np.all((poses[:, 1] > 110) & (poses[:, 1] < length - 110))


def test_distractors_move_and_push():
    env = bbs.BringBackShapesEnv(num_distractors=2)
    env.reset(seed=3)
    start = env.true_state()["distractor_poses"].copy()
    for _ in range(30):
        env.step(np.zeros(2, np.float32) - [0, 1])  # agent idle (force 0)
    moved = np.linalg.norm(env.true_state()["distractor_poses"][:, :2] - start[:, :2], axis=1)
    assert np.all(moved > 5.0)


# ------------------------------------------------------------------------------------ API
def test_reset_observation_shows_the_new_episode():
    env, fresh = (bbs.BringBackShapesEnv(num_distractors=2) for _ in range(2))
    env.reset(seed=0)
    for _ in range(20):
        last, *_ = env.step(RIGHT)
    first, _ = env.reset(seed=5)
    assert not np.array_equal(first, last)
    assert np.array_equal(first, fresh.reset(seed=5)[0])


DETERMINISM_SCRIPT = """
import hashlib, numpy as np, bbs
env = bbs.make("bbs_basic_d2")
obs, _ = env.reset(seed=123)
h = hashlib.sha256(obs.tobytes())
actions = np.random.default_rng(7).uniform(-1, 1, (60, 2)).astype(np.float32)
for a in actions:
    obs, r, *_ = env.step(a)
    h.update(obs.tobytes()); h.update(np.float64(r).tobytes())
h.update(env.true_state()["agent_pose"].tobytes())
print(h.hexdigest())
"""


def test_bit_identical_across_processes():
    outputs = {
        subprocess.run([sys.executable, "-c", DETERMINISM_SCRIPT], capture_output=True, text=True,
                       check=True, cwd=REPO_ROOT, env={"PYTHONHASHSEED": seed}).stdout.strip()
        for seed in ("1", "2")
    }
    local = {}
    exec(DETERMINISM_SCRIPT.replace("print(h.hexdigest())", "out = h.hexdigest()"), local)
    assert len(outputs) == 1 and outputs == {local["out"]}


def test_layout_reproduces_the_episode():
    env = bbs.BringBackShapesEnv()
    first, _ = env.reset(seed=11)
    saved = env.layout.to_dict()
    actions = np.random.default_rng(2).uniform(-1, 1, (40, 2))
    run = [env.step(a)[0] for a in actions]
    replay = bbs.BringBackShapesEnv()
    again, _ = replay.reset(seed=99, options={"layout": saved})
    assert np.array_equal(first, again)
    assert digest(run) == digest(replay.step(a)[0] for a in actions)
    placed = replay.true_state()
    assert placed["object_shapes"] == tuple(o["shape"] for o in saved["objects"])


def test_layout_places_entities_exactly():
    scene = layout(agent=(300.0, 400.0), agent_angle=0.5,
                   objects=[square(200, 200, "blue", "hexagon", 1.0)], distractors=[(450.0, 250.0)])
    env = bbs.BringBackShapesEnv()
    env.reset(options={"layout": scene})
    s = env.true_state()
    assert s["agent_pose"].tolist() == [300.0, 400.0, 0.5]
    assert s["object_poses"].tolist() == [[200.0, 200.0, 1.0]]
    assert (s["object_shapes"], s["object_colours"]) == (("hexagon",), ("blue",))
    assert s["distractor_poses"].tolist() == [[450.0, 250.0, 0.0]]


@pytest.mark.parametrize("bad, message", [
    ({"objects": [square(200, 200, shape="circle")]}, "'circle'"),
    ({"objects": [square(200, 200, colour="pink")]}, "'pink'"),
    ({"objects": []}, "at least one object"),
    ({"goal_y": 500.0, "objects": [square(200, 200)]}, "goal_y=500.0"),
    ({"objects": [{"position": (math.nan, 1.0), "shape": "square", "colour": "red"}]}, "finite"),
    ({"agent": {"position": (900.0, 100.0)}}, r"\(900.0, 100.0\) lies outside the 800x700"),
])
def test_bad_layout_is_rejected(bad, message):
    env = bbs.BringBackShapesEnv()
    with pytest.raises(ValueError, match=message):
        env.reset(options={"layout": layout() | bad})


@pytest.mark.parametrize("bad, message", [
    ({"agent": {"position": (50, 50)}}, r"layout agent at \(50, 50\) overlaps the arena wall"),
    ({"agent": {"position": (300.0, 130.0)}}, r"agent at \(300, 130\) overlaps the arena wall "
                                              r"\(top wall\)"),
    ({"objects": [square(200, 200), square(60, 300)]},
     r"layout objects\[1\] at \(60, 300\) overlaps the arena wall \(left wall\)"),
    ({"distractors": [{"position": (300.0, 690.0)}]},
     r"layout distractors\[0\] at \(300, 690\) overlaps the arena wall \(bottom wall\)"),
    ({"distractors": [{"position": (400.0, 580.0)}]}, r"distractors\[0\] at \(400, 580\)"),
])
def test_layout_entities_inside_walls_are_rejected(bad, message):
    # The agent at (50, 50) used to be pushed out of the arena, to y = -14.9, and stay there.
    env = bbs.BringBackShapesEnv()
    with pytest.raises(ValueError, match=message):
        env.reset(options={"layout": layout(objects=[square(200, 200)]) | bad})


def test_layouts_touching_walls_or_past_the_goal_line_are_accepted():
    # The agent's disc may touch a wall; past the goal line it starts clamped (x = 560); object
    # shapes may reach into walls (only their origin must lie inside), as sampled ones do.
    env = bbs.BringBackShapesEnv()
    env.reset(options={"layout": layout(agent=(140.0, 140.0), objects=[square(125, 560, angle=1)],
                                        distractors=[(137.0, 563.0)])})
    env.reset(options={"layout": layout(agent=(640.0, 230.0), objects=[square(200, 200)])})
    assert env.true_state()["agent_pose"][0] == 560.0


@pytest.mark.parametrize("scale", [bbs.env.MIN_ARENA_SCALE, 1.0, 1.6])
def test_sampled_layouts_pass_the_layout_checks(scale):
    """Every layout the spawn rule draws can be replayed (``to_dict`` -> ``reset``)."""
    rng = np.random.default_rng(0)
    default = arena_geometry(scale)
    for _ in range(300):
        goal_y = float(rng.uniform(*default.goal_y_range))
        sampled = sample_layout(rng, arena_geometry(scale, goal_y), 5, 4, goal_y)
        assert parse_layout(sampled.to_dict(), default) == sampled


def test_variants_registry_and_task_names():
    assert len(bbs.VARIANTS) == 16
    assert bbs.variant_kwargs("bbs_medium_d4") == {"arena_scale": 1.4, "num_distractors": 4}
    assert bbs.variant_kwargs("bbs_basic") == {"arena_scale": 1.0, "num_distractors": 0}
    with pytest.raises(ValueError, match="bbs_large_d4"):
        bbs.variant_kwargs("bbs_huge")
    for name, gym_id in bbs.VARIANT_IDS.items():
        assert gymnasium.spec(gym_id).kwargs == bbs.VARIANTS[name]
    env = gymnasium.make("BringBackShapes-Large-D1-v0")
    assert (env.unwrapped.arena_scale, env.unwrapped.num_distractors) == (1.6, 1)
    assert env.reset(seed=0)[0].shape == (64, 64, 3)
    custom = gymnasium.make("BringBackShapes-v0", num_objects=2, obs_size=32)
    assert custom.reset(seed=0)[0].shape == (32, 32, 3)
    assert len(custom.unwrapped.true_state()["object_poses"]) == 2


def test_gymnasium_env_checker_passes_without_warnings(monkeypatch):
    """With the render check: every advertised render mode is made and rendered."""
    from gymnasium.utils.env_checker import check_env

    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")  # headless window, where pygame is installed
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(gymnasium.make("BringBackShapes-Basic-D2-v0").unwrapped)
        check_env(gymnasium.make("BringBackShapes-v0", render_mode="rgb_array").unwrapped)


def test_render_modes_advertise_human_only_with_pygame(monkeypatch):
    import importlib.util

    installed = importlib.util.find_spec("pygame") is not None
    expected = ["human", "rgb_array"] if installed else ["rgb_array"]
    assert bbs.BringBackShapesEnv.metadata["render_modes"] == expected
    monkeypatch.setattr(bbs.window, "pygame_available", lambda: False)
    assert bbs.BringBackShapesEnv().metadata["render_modes"] == ["rgb_array"]
    with pytest.raises(ImportError, match=r"vsgjax\[play\]"):
        bbs.BringBackShapesEnv(render_mode="human")
    monkeypatch.setattr(bbs.window, "pygame_available", lambda: True)
    assert bbs.BringBackShapesEnv().metadata["render_modes"] == ["human", "rgb_array"]


# ------------------------------------------------------------------------------------ options
def _counts(env, seeds):
    out = []
    for seed in seeds:
        env.reset(seed=seed)
        s = env.true_state()
        out.append((len(s["object_poses"]), len(s["distractor_poses"]), s["goal_y"]))
    return out


def test_variable_counts_and_goal_position():
    fixed = _counts(bbs.BringBackShapesEnv(num_objects=3, num_distractors=2), range(5))
    assert set(fixed) == {(3, 2, 237.5)}
    env = bbs.BringBackShapesEnv(num_distractors=4, variable_num_objects=True,
                                 variable_num_distractors=True, variable_goal_position=True)
    varied = _counts(env, range(40))
    objects, distractors, goals = zip(*varied, strict=True)
    assert set(objects) == set(range(1, 6)) and set(distractors) == {0, 1, 2, 3, 4}
    low, high = env.geometry.goal_y_range
    assert len(set(goals)) == 40 and all(low <= g <= high for g in goals)
    env.reset(seed=0)  # the wall blocks move with the opening
    g = env.geometry
    assert g.walls[4].y1 == g.goal_y and g.walls[5].y0 == g.goal_y + g.goal_height


def test_view_size_obs_size_canvas_and_repeat_options():
    scene = {"layout": layout(agent=(350.0, 350.0), objects=[square(200, 200)])}
    agent_colour = np.array(VIEW_PALETTE.agent)

    def agent_pixels(**kwargs):
        obs, _ = bbs.BringBackShapesEnv(**kwargs).reset(options=scene)
        return int(np.all(obs == agent_colour, axis=-1).sum()), obs

    default, obs = agent_pixels()
    zoomed, _ = agent_pixels(agent_view_size=60)
    small, small_obs = agent_pixels(obs_size=32)
    assert zoomed > 3 * default and small < default / 2 and small_obs.shape == (32, 32, 3)
    smooth, smooth_obs = agent_pixels(canvas_size=256)
    assert smooth_obs.shape == (64, 64, 3) and np.abs(smooth_obs.astype(int) - obs).mean() < 3
    env = bbs.BringBackShapesEnv(action_repeat=2)
    env.reset(seed=0)
    assert env.step(RIGHT)[4]["sub_steps"] == 2


def test_raw_actions_match_normalised_ones():
    scene = {"layout": layout(objects=[square(200, 200)])}
    normalised, raw = bbs.BringBackShapesEnv(), bbs.BringBackShapesEnv(normalize_actions=False)
    assert raw.action_space.high.tolist() == pytest.approx([2 * math.pi, 400.0])
    normalised.reset(options=scene)
    raw.reset(options=scene)
    for a in np.random.default_rng(0).uniform(-1, 1, (10, 2)):
        expected, *_ = normalised.step(a)
        got, *_ = raw.step(((a[0] + 1) * math.pi, (a[1] + 1) * 200))
        assert np.array_equal(got, expected)


def test_out_of_range_actions_are_clipped_and_bad_actions_raise():
    clipped, exact = bbs.BringBackShapesEnv(), bbs.BringBackShapesEnv()
    clipped.reset(seed=4)
    exact.reset(seed=4)
    assert np.array_equal(clipped.step([-7.0, 3.0])[0], exact.step([-1.0, 1.0])[0])
    for bad, message in [([math.nan, 0.0], "finite"), ([0.0, math.inf], "finite"),
                         ([None, 0], "finite"), (["left", 0.0], "finite"),
                         ([0.0, 0.0, 0.0], r"shape \(2,\)"), (0.5, r"shape \(2,\)")]:
        with pytest.raises(ValueError, match=message):
            exact.step(bad)


def test_step_before_reset_and_after_the_end_raise():
    env = bbs.BringBackShapesEnv(time_limit=0)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(RIGHT)
    env.reset(seed=0)
    assert env.step(RIGHT)[3]  # time_limit 0: the first agent step runs 2 sub-steps and ends
    with pytest.raises(RuntimeError, match="reset"):
        env.step(RIGHT)


def test_state_in_info_option():
    env = bbs.BringBackShapesEnv(include_state_in_info=True, num_distractors=1)
    _, info = env.reset(seed=0)
    assert set(info["state"]) >= {"agent_pose", "object_poses", "distractor_velocities"}
    assert "state" not in bbs.BringBackShapesEnv().reset(seed=0)[1]


@pytest.mark.parametrize("kwargs, message", [
    ({"arena_scale": 0}, "arena_scale must be a finite number > 0; got 0"),
    ({"arena_scale": -1.0}, "got -1.0"),
    ({"arena_scale": math.inf}, "got inf"),
    ({"num_objects": 0}, "num_objects must be an integer >= 1; got 0"),
    ({"num_objects": 2.5}, "num_objects.*got 2.5"),
    ({"num_distractors": -1}, "num_distractors must be an integer >= 0; got -1"),
    ({"agent_view_size": 400}, "agent_view_size=400"),
    ({"agent_view_size": 0}, "agent_view_size must be an integer >= 1; got 0"),
    ({"action_repeat": 0}, "action_repeat.*got 0"),
    ({"time_limit": -5}, "time_limit.*got -5"),
    ({"obs_size": 0}, "obs_size.*got 0"),
    ({"canvas_size": 32}, "canvas_size must be an integer >= 64; got 32"),
    ({"render_mode": "video"}, "'video'"),
])
def test_bad_options_are_rejected_with_the_value(kwargs, message):
    with pytest.raises(ValueError, match=message):
        bbs.BringBackShapesEnv(**kwargs)


@pytest.mark.parametrize("scale", [0.358, 0.39, 0.4, 0.47])
def test_too_small_arena_scale_is_rejected_at_construction(scale):
    # Below 0.4 reset() used to fail inside numpy; below 0.475 the agent, clamped at the goal
    # line (goal_x - 15), starts inside the left wall: 2 * 125 (walls) + 100 (goal) + 2 * 15.
    smallest = bbs.env.MIN_ARENA_SCALE
    assert smallest == 0.475 and arena_geometry(smallest).goal_x - AGENT_RADIUS == 125 + 15
    with pytest.raises(ValueError, match=rf"arena_scale={scale} is too small: the smallest valid "
                                         rf"scale is 0\.475"):
        bbs.BringBackShapesEnv(arena_scale=scale)
    with pytest.raises(ValueError, match="too small"):
        bbs.BringBackShapesEnv(arena_scale=math.nextafter(smallest, 0.0))


def test_smallest_arena_scale_resets_and_steps():
    env = bbs.BringBackShapesEnv(arena_scale=bbs.env.MIN_ARENA_SCALE, num_distractors=4,
                                 variable_goal_position=True)
    rng = np.random.default_rng(0)
    for seed in range(10):
        env.reset(seed=seed)
        for _ in range(10):
            _, _, terminated, truncated, _ = env.step(rng.uniform(-1, 1, 2))
            if terminated or truncated:
                break
        state = env.true_state()
        assert 110 < state["agent_pose"][0] < env.geometry.goal_x
        assert 110 < state["agent_pose"][1] < env.geometry.length - 110


def test_unknown_reset_option_is_rejected():
    with pytest.raises(ValueError, match="'layuot'"):
        bbs.BringBackShapesEnv().reset(options={"layuot": {}})


# ------------------------------------------------------------------------------------ metrics
def test_discovery_tracker_on_a_hand_made_episode():
    tracker = DiscoveryTracker(4)
    tracker.observe(0, [2])
    tracker.observe(3, [0, 2])
    tracker.observe(7, [0, 1])
    summary = tracker.summary(episode_length=10, scored=np.array([True, False, False, True]))
    assert summary["first_visit"] == (3, 7, 0, -1)
    assert summary["mean_first_visit"] == pytest.approx(10 / 3)
    assert summary["never_visited"] == 25.0
    assert summary["visited_not_scored"] == pytest.approx(200 / 3)  # objects 1 and 2 of 0, 1, 2
    assert summary["scored"] == 2 and summary["episode_length"] == 10
    empty = DiscoveryTracker(2).summary(5, np.zeros(2, bool))
    assert empty["never_visited"] == 100.0 and math.isnan(empty["visited_not_scored"])


def test_discovery_in_an_episode_uses_complete_visibility():
    # Object 0 fully in view at reset; object 1 straddles the view edge; object 2 is far away.
    scene = layout(agent=(300.0, 350.0), objects=[square(320, 300), square(410, 300),
                                                  square(140, 520)])
    env = bbs.BringBackShapesEnv(time_limit=6)
    env.reset(options={"layout": scene})
    done = False
    while not done:
        *_, terminated, truncated, info = env.step(np.zeros(2) - [0, 1])
        done = terminated or truncated
    d = info["discovery"]
    assert d["first_visit"] == (0, -1, -1) and d["episode_length"] == 2
    assert d["never_visited"] == pytest.approx(200 / 3) and d["visited_not_scored"] == 100.0


# ------------------------------------------------------------------------------------ pixels
KNOWN_SCENE = layout(
    agent=(520.0, 350.0),
    objects=[square(400, 230 + 50 * i, colour) for i, colour in enumerate(SQUARE_COLOURS)],
    distractors=[(500.0, 420.0)],
)


def _pixel(env, x, y):
    """Observation pixel (row, col) whose centre is nearest to world point (x, y)."""
    box_x0, box_y0, scale = 520 - 125, 350 - 125, env.observation_space.shape[0] / 250
    return round((y - box_y0 + 0.5) * scale - 0.5), round((x - box_x0 + 0.5) * scale - 0.5)


def test_observation_colours_for_a_known_layout():
    env = bbs.BringBackShapesEnv(render_mode="rgb_array")
    obs, _ = env.reset(options={"layout": KNOWN_SCENE})
    expected = {
        (470.0, 300.0): (50, 50, 50),  # floor
        (610.0, 230.0): (141, 151, 151),  # goal block (wall)
        (610.0, 350.0): (50, 129, 90),  # goal
        (520.0, 342.0): (93, 129, 160),  # agent, above its orientation line
        (500.0, 420.0): (165, 137, 137),  # distractor
    }
    expected |= {(425.0, 255.0 + 50 * i): view_colour(c) for i, c in
                 enumerate(bbs.geometry.OBJECT_COLOURS.values())}
    for (x, y), colour in expected.items():
        assert tuple(obs[_pixel(env, x, y)]) == colour, (x, y)
    assert [view_colour(bbs.geometry.OBJECT_COLOURS[c]) for c in SQUARE_COLOURS] == [
        (205, 151, 50), (50, 50, 205), (50, 205, 50), (205, 50, 50), (148, 70, 196)]
    spec_table = [(50, 50, 50), (141, 151, 151), (50, 129, 90), (93, 129, 160), (77, 88, 99),
                  (165, 137, 137)]
    p = VIEW_PALETTE
    assert [p.background, p.wall, p.goal, p.agent, p.agent_line, p.distractor] == spec_table
    arena = env.render()
    assert arena.shape == (700, 800, 3)
    screen = {(200, 550): (0, 0, 0), (300, 300): (0, 0, 0), (50, 50): (149, 165, 166),
              (660, 350): (0, 130, 65), (425, 255): (205, 151, 50), (470, 300): (50, 50, 50)}
    for (x, y), colour in screen.items():
        assert tuple(arena[y, x]) == colour, (x, y)


def test_full_arena_goal_pixels_match_the_original():
    env = bbs.BringBackShapesEnv(render_mode="rgb_array")
    env.reset(options={"layout": layout(agent=(200.0, 200.0), objects=[square(150, 500)])})
    green = np.all(env.render() == (0, 130, 65), axis=-1)
    rows, cols = np.flatnonzero(green[:, 600]), np.flatnonzero(green[350])
    assert (rows.min(), rows.max(), cols.min(), cols.max()) == (239, 461, 575, 674)


VIEW_SCALE = 64 / 250  # the 250x250 view box onto the 64x64 observation (bbs/render.py)
FAR_OBJECT = square(140, 140, shape="triangle")  # out of view: a layout needs an object


def _area_and_centroid(vertices):
    """Shoelace area and centroid of a simple polygon."""
    area2 = cx = cy = 0.0
    for (x0, y0), (x1, y1) in zip(vertices, (*vertices[1:], vertices[0]), strict=True):
        cross = x0 * y1 - x1 * y0
        area2, cx, cy = area2 + cross, cx + (x0 + x1) * cross, cy + (y0 + y1) * cross
    return abs(area2) / 2, (cx / (3 * area2), cy / (3 * area2))


def _drawn_area(obs, colour, box, centre, reach=45.0):
    """Observation px^2 of ``colour`` within ``reach`` world px of ``centre``.

    Each pixel counts the fraction of the way it lies from the background to ``colour``
    (projected on that direction, clipped to [0, 1]): 1 for a pixel of the shape's colour,
    the blend fraction for a blended one.
    """
    background = np.array(VIEW_PALETTE.background, float)
    direction = np.array(colour, float) - background
    share = np.clip((obs - background) @ direction / (direction @ direction), 0.0, 1.0)
    centres = (np.arange(obs.shape[0]) + 0.5) / VIEW_SCALE - 0.5  # pixel centres, world px
    near_x, near_y = (np.abs(centres + box.x0 - centre[0]) < reach,
                      np.abs(centres + box.y0 - centre[1]) < reach)
    return float(share[np.outer(near_y, near_x)].sum())


@pytest.mark.parametrize("kind", [*OBJECT_SHAPES, "distractor", "agent"])
def test_drawn_area_of_every_shape_is_unbiased(kind):
    """Mean drawn area over random sub-pixel positions and angles: within 3% of the true area.

    The true area is the polygon's (disc's) area scaled to the 64x64 view, by (64/250)^2.
    Before pixel-centre sampling the shapes were 15-39% too large (triangle 1.39x).
    """
    env = bbs.BringBackShapesEnv()
    rng = np.random.default_rng(0)
    ratios = []
    for _ in range(40):
        angle = float(rng.uniform(0, 2 * math.pi))
        cx, cy = (float(v) for v in rng.uniform(-4, 4, 2) + (250.0, 310.0))
        if kind == "agent":
            scene = layout(agent=(cx, cy), agent_angle=angle, objects=[FAR_OBJECT])
            area, colour = math.pi * AGENT_RADIUS**2, VIEW_PALETTE.agent
        else:
            vertices = DISTRACTOR_VERTICES if kind == "distractor" else OBJECT_SHAPES[kind]
            area, (gx, gy) = _area_and_centroid(vertices)
            c, s = math.cos(angle), math.sin(angle)
            origin = (cx - (c * gx - s * gy), cy - (s * gx + c * gy))  # centroid at (cx, cy)
            if kind == "distractor":
                scene = layout(agent=(330.0, 380.0), objects=[FAR_OBJECT])
                scene["distractors"] = [{"position": origin, "angle": angle}]
                colour = VIEW_PALETTE.distractor
            else:
                scene = layout(agent=(330.0, 380.0), objects=[square(*origin, "red", kind, angle)])
                colour = VIEW_PALETTE.objects["red"]
        obs, _ = env.reset(options={"layout": scene})
        box = view_box(env.scene.agent, env.agent_view_size, env.geometry)
        ratios.append(_drawn_area(obs, colour, box, (cx, cy)) / (area * VIEW_SCALE**2))
    assert np.mean(ratios) == pytest.approx(1.0, abs=0.03)


def test_observation_differs_from_the_original_pipeline_only_on_few_edge_pixels():
    """Against the original's pipeline (250x250 frame, bilinear to 64; emulated): at most the
    2.1% of pixels that differed before pixel-centre sampling, and only on shape edges or the
    agent's orientation line (drawn one pixel wide in its area-averaged colour)."""
    p = VIEW_PALETTE
    line = [round(a + VIEW_SCALE * (b - a)) for a, b in zip(p.agent, p.agent_line, strict=True)]
    shares = []
    for seed in range(3):
        env = bbs.make("bbs_basic_d2")
        env.reset(seed=seed)
        rng = np.random.default_rng(seed)
        for step in range(24):
            obs, *_ = env.step(rng.uniform(-1, 1, 2))
            if step % 6 != 5:
                continue
            box = view_box(env.scene.agent, env.agent_view_size, env.geometry)
            reference = original_pipeline_view(env.scene, env.geometry, box).astype(int)
            differs = np.any(obs != reference, axis=-1)
            shares.append(differs.mean())
            padded = np.pad(reference, ((1, 1), (1, 1), (0, 0)), mode="edge")
            windows = np.lib.stride_tricks.sliding_window_view(padded, (3, 3), axis=(0, 1))
            on_edge = np.any(windows.max(axis=(-2, -1)) != windows.min(axis=(-2, -1)), axis=-1)
            on_line = np.all(obs == line, axis=-1)
            assert np.all((on_edge | on_line)[differs])  # on_edge: a 3x3 window of 2+ colours
    assert np.mean(shares) <= 0.021


# ------------------------------------------------------------------------------------ vector
def test_vector_envs_sync_and_async():
    make = functools.partial(bbs.make, "bbs_basic_d1", time_limit=14)  # picklable for spawn
    single = [make() for _ in range(2)]
    expected = [env.reset(seed=s)[0] for env, s in zip(single, (5, 6), strict=True)]
    actions = np.random.default_rng(0).uniform(-1, 1, (5, 2, 2)).astype(np.float32)
    # spawn, not fork: forking a process that has imported JAX can deadlock
    spawn_async = functools.partial(gymnasium.vector.AsyncVectorEnv, context="spawn")
    for vector_cls in (gymnasium.vector.SyncVectorEnv, spawn_async):
        envs = vector_cls([make, make])
        obs, _ = envs.reset(seed=[5, 6])
        assert np.array_equal(obs, np.stack(expected))
        ends = []
        for a in actions:
            obs, reward, terminated, truncated, info = envs.step(a)
            if truncated.any():
                ends.append((truncated.tolist(), info["discovery"]["episode_length"].tolist()))
        assert ends == [([True, True], [4, 4])]
        envs.close()


# ------------------------------------------------------------------------------------ extras
def test_chipmunk_fast_path_agrees_with_the_public_api():
    from bbs import _chipmunk

    sim = simulation(layout(agent=(300.0, 350.0), agent_angle=0.25, objects=[square(200, 200)]))
    body = sim.agent
    body.velocity = (12.0, -3.0)
    assert _chipmunk.position(body) == tuple(body.position)
    assert _chipmunk.velocity(body) == tuple(body.velocity)
    assert _chipmunk.angle(body) == body.angle
    _chipmunk.set_force_and_torque(body, 1.0, 2.0, 3.0)
    assert (tuple(body.force), body.torque) == ((1.0, 2.0), 3.0)
    twin = simulation(layout(agent=(300.0, 350.0), agent_angle=0.25, objects=[square(200, 200)]))
    twin.agent.velocity, twin.agent.force, twin.agent.torque = (12.0, -3.0), (1.0, 2.0), 3.0
    _chipmunk.step(sim.space, DT)
    twin.space.step(DT)
    assert tuple(body.position) == tuple(twin.agent.position) and body.angle == twin.agent.angle


def test_keyboard_mapping_of_play():
    from bbs.play import action_from_keys

    assert action_from_keys(False, False, False, False) == (0.0, 0.0)
    assert action_from_keys(True, False, False, False) == (0.0, 400.0)
    assert action_from_keys(False, False, False, True) == (pytest.approx(1.5 * math.pi), 400.0)
    assert action_from_keys(False, True, True, False) == (pytest.approx(0.75 * math.pi), 400.0)
