"""Distracting backgrounds of the dmc_ tasks (vsgjax/envs/backgrounds.py)."""

import dataclasses
import re

import imageio.v3 as iio
import numpy as np
import pytest

from vsgjax import train
from vsgjax.config import ConfigError, make_config
from vsgjax.config.schema import BACKGROUNDS
from vsgjax.envs import make_env
from vsgjax.envs.backgrounds import (
    Color,
    Dots,
    Noise,
    Video,
    composite,
    make_background,
    read_video,
    split,
    video_files,
)

SIZE = 32
TASK = "dmc_cartpole_balance"


def rng(seed):
    return np.random.default_rng(seed)


def frames_of(source, seed, steps=4):
    return np.stack([source.reset(rng(seed))] + [source.step() for _ in range(steps)])


def video_colour(video, frame):
    """The solid colour of frame ``frame`` of test video ``video`` (exact in a GIF)."""
    return np.array([40 * frame, 100 + 100 * video, 10], np.uint8)


@pytest.fixture(scope="module")
def video_dir(tmp_path_factory):
    """Two 5-frame 16x16 GIFs of known solid colours (written out of name order)."""
    folder = tmp_path_factory.mktemp("videos")
    for video in (1, 0):
        frames = np.stack([np.broadcast_to(video_colour(video, t), (16, 16, 3))
                           for t in range(5)])
        iio.imwrite(folder / f"clip{video}.gif", frames, loop=0)
    (folder / "notes.txt").write_text("not a video")
    return folder


def env_config(**changes):
    return dataclasses.replace(make_config(TASK, size="paper").env, image_size=SIZE, **changes)


def test_composite_replaces_exactly_the_bluish_pixels():
    frame = np.array([[[10, 20, 30], [30, 20, 10], [10, 30, 30], [30, 10, 30], [5, 5, 5]]],
                     np.uint8)
    background = np.full_like(frame, 99)
    out = composite(frame, background)
    np.testing.assert_array_equal(out[0, 0], [99, 99, 99])  # blue > red and blue > green
    np.testing.assert_array_equal(out[0, 1:], frame[0, 1:])  # red, blue = green or red, grey
    assert out.dtype == np.uint8


@pytest.fixture(scope="module")
def dmc_frames():
    """The reset and next observation of one seed, without and with a noise background."""
    plain, noisy = (make_env(env_config(background=kind), seed=3) for kind in ("none", "noise"))
    frames = []
    for env in (plain, noisy):
        first, _ = env.reset()
        second = env.step(np.zeros(env.action_space.shape, np.float32))[0]
        frames.append(np.stack([first, second]))
        env.close()
    return frames


def test_a_real_dmc_frame_keeps_the_agent_and_shows_the_background(dmc_frames):
    plain, noisy = dmc_frames
    mask = (plain[..., 2] > plain[..., 0]) & (plain[..., 2] > plain[..., 1])
    assert 0 < mask.mean() < 1, "the frame has both a bluish backdrop and an agent"
    np.testing.assert_array_equal(noisy[~mask], plain[~mask])
    assert (noisy[mask] != plain[mask]).any(axis=-1).mean() > 0.9
    both = mask[0] & mask[1]
    assert (noisy[0][both] != noisy[1][both]).any(axis=-1).mean() > 0.9, "the step draws anew"


def test_the_env_composites_the_source_frames_reset_and_step():
    """Reset and each step use the source's next frame, restarted from the env's RNG."""
    env = make_env(env_config(background="color"), seed=5)
    first, _ = env.reset()
    second = env.step(np.zeros(env.action_space.shape, np.float32))[0]
    colour = Color(SIZE).reset(np.random.default_rng(5))
    for frame in (first, second):
        mask = (frame == colour).all(-1)
        assert mask.mean() > 0.3, "the bluish pixels show the episode's colour"
    env.close()


@pytest.mark.parametrize("source", [Color(SIZE), Noise(SIZE), Dots(SIZE)],
                         ids=["color", "noise", "dots"])
def test_sources_are_determined_by_the_seed(source):
    first = frames_of(source, 0)
    assert first.shape == (5, SIZE, SIZE, 3) and first.dtype == np.uint8
    np.testing.assert_array_equal(frames_of(source, 0), first)
    assert not np.array_equal(frames_of(source, 1), first)


def test_noise_changes_every_step_and_color_never_within_an_episode():
    noise, color = frames_of(Noise(SIZE), 0), frames_of(Color(SIZE), 0)
    assert all(not np.array_equal(a, b) for a, b in zip(noise, noise[1:], strict=False))
    assert (color == color[0, 0, 0]).all()


def test_bouncing_dots_keep_their_speed_and_stay_inside():
    dots = Dots(SIZE, num=6, speed=0.2, laws=("bounce",))
    dots.reset(rng(0))
    speed, low, high = 0.2, dots.radius, 1 - dots.radius
    positions = [dots.positions]
    for _ in range(30):
        dots.step()
        positions.append(dots.positions)
        np.testing.assert_allclose(np.linalg.norm(dots.velocities, axis=-1), speed)
    positions = np.stack(positions)
    assert ((positions >= low) & (positions <= high)).all()
    assert (np.diff(np.sign(np.diff(positions, axis=0)), axis=0) != 0).any(), "some dot bounced"


def test_a_bouncing_dot_reflects_at_the_border_and_turns_back():
    dots = Dots(SIZE, num=1, laws=("bounce",))
    dots.reset(rng(0))
    high = 1 - dots.radius
    dots.positions, dots.velocities = np.array([[0.5, high - 0.01]]), np.array([[0.0, 0.1]])
    path = []
    for _ in range(3):
        dots.step()
        path.append(dots.positions[0, 1])
    np.testing.assert_allclose(path, [high - 0.09, high - 0.19, high - 0.29])
    np.testing.assert_allclose(dots.positions[0, 0], 0.5)


def test_brownian_dots_take_unequal_random_steps_and_stay_inside():
    dots = Dots(SIZE, num=4, laws=("brownian",))
    dots.reset(rng(0))
    positions = [dots.positions]
    for _ in range(20):
        dots.step()
        positions.append(dots.positions)
    positions = np.stack(positions)
    steps = np.diff(positions, axis=0)
    assert np.unique(np.round(steps, 9)).size > steps.size // 2
    assert ((positions >= dots.radius) & (positions <= 1 - dots.radius)).all()


def test_dots_draw_their_colours_on_black():
    dots = Dots(SIZE, num=3, laws=("bounce",))
    frame = dots.reset(rng(0))
    colours = {tuple(c) for c in frame.reshape(-1, 3)}
    assert colours == {(0, 0, 0), *map(tuple, dots.colours)}


def test_splits_are_disjoint_halves_covering_the_files(video_dir):
    files = video_files(str(video_dir))
    assert [f.name for f in files] == ["clip0.gif", "clip1.gif"]
    train, test = split(files, test=False), split(files, test=True)
    assert not set(train) & set(test) and sorted(train + test) == files
    many = [video_dir / f"v{i}.mp4" for i in range(7)]
    assert len(split(many, False)) == 4 and set(split(many, False) + split(many, True)) == set(
        many)


def test_a_video_plays_from_a_random_start_one_frame_per_step_and_loops(video_dir):
    video = make_background("video", 8, str(video_dir), test=True)
    assert [f.name for f in video.files] == ["clip1.gif"]
    starts = set()
    for seed in range(6):
        first = video.reset(rng(seed))
        start = video.frame_index
        starts.add(start)
        frames = [first] + [video.step() for _ in range(6)]
        for step, frame in enumerate(frames):
            assert frame.shape == (8, 8, 3)
            np.testing.assert_array_equal(frame, np.broadcast_to(
                video_colour(1, (start + step) % 5), (8, 8, 3)))
        video.reset(rng(seed))
        assert video.frame_index == start
    assert len(starts) > 1


def test_read_video_resizes_and_keeps_every_frame(video_dir):
    frames = read_video(video_dir / "clip0.gif", 4)
    assert frames.shape == (5, 4, 4, 3)
    np.testing.assert_array_equal(frames[:, 0, 0], [video_colour(0, t) for t in range(5)])


def test_train_envs_play_the_train_split(video_dir):
    video = make_background("video", 8, str(video_dir), test=False)
    assert isinstance(video, Video)
    frame = video.reset(rng(0))
    assert frame[0, 0, 1] == video_colour(0, 0)[1]


def test_every_choice_builds_a_source():
    assert make_background("none", SIZE) is None
    for kind in set(BACKGROUNDS) - {"none", "video"}:
        assert make_background(kind, SIZE).reset(rng(0)).shape == (SIZE, SIZE, 3)


def test_backgrounds_on_another_family_name_the_task_and_the_option():
    with pytest.raises(ConfigError, match=r"env.background='noise' is an option of the "
                       r"dmc_<domain>_<task> tasks; valid for task 'bbs_basic'"):
        make_config("bbs_basic", overrides=["env.background=noise"])
    with pytest.raises(ConfigError, match=r"env.background_dir='x' .* task 'atari_pong'"):
        make_config("atari_pong", overrides=["env.background_dir=x"])


def test_bad_video_folders_are_refused_naming_the_value(video_dir, tmp_path, capsys):
    with pytest.raises(ConfigError, match="without env.background_dir; valid"):
        make_config(TASK, overrides=["env.background=video"])
    missing = tmp_path / "missing"
    one = tmp_path / "one"
    one.mkdir()
    (one / "clip0.gif").write_bytes((video_dir / "clip0.gif").read_bytes())
    for folder, message in ((missing, f"background_dir='{missing}' is not a folder"),
                            (one, r"holds 1 video file\(s\) .*valid: at least 2")):
        with pytest.raises(ConfigError, match=message):
            video_files(str(folder))
        logdir = tmp_path / "run"
        assert train.main(["--task", TASK, "--size", "debug", "--logdir", str(logdir),
                           "env.background=video", f"env.background_dir={folder}"]) == 2
        assert re.search(message, capsys.readouterr().err) and not logdir.exists()
    with pytest.raises(ConfigError, match="valid: env.background_dir=''"):
        make_config(TASK, overrides=["env.background=dots", f"env.background_dir={video_dir}"])
    with pytest.raises(ConfigError, match="env.background.*got 'snow'; valid: none, video"):
        make_config(TASK, overrides=["env.background=snow"])
    config = make_config(TASK, overrides=["env.background=video",
                                          f"env.background_dir={video_dir}"])
    assert config.env.background == "video"
