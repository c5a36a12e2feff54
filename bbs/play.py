"""Drive the agent with the keyboard: ``python -m bbs.play [--task bbs_basic_d2] [--seed 0]``.

Arrow keys push the agent (diagonals too) with full force; no key means no force. ``r``
starts a new episode, ``Esc`` or ``q`` quits. Needs pygame (extra ``play``).
"""

import argparse
import math

import bbs
from bbs.env import MAX_FORCE
from bbs.window import Window, import_pygame


def action_from_keys(right: bool, left: bool, down: bool, up: bool) -> tuple[float, float]:
    """Raw (angle, force): angle 0 pushes right (+x), pi/2 down (+y, screen coordinates)."""
    dx, dy = int(right) - int(left), int(down) - int(up)
    if dx == 0 and dy == 0:
        return 0.0, 0.0
    return math.atan2(dy, dx) % (2 * math.pi), MAX_FORCE


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="bbs_basic", choices=sorted(bbs.VARIANTS))
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    pygame = import_pygame()
    env = bbs.make(args.task, render_mode="rgb_array", normalize_actions=False)
    env.reset(seed=args.seed)
    frame = env.render()
    window = Window(f"BringBackShapes {args.task}", frame.shape[1], frame.shape[0])
    episode_return = 0.0
    while not window.closed:
        window.show(frame, env.metadata["render_fps"])
        keys = pygame.key.get_pressed()
        if keys[pygame.K_ESCAPE] or keys[pygame.K_q]:
            break
        if keys[pygame.K_r]:
            env.reset()
            episode_return = 0.0
        action = action_from_keys(keys[pygame.K_RIGHT], keys[pygame.K_LEFT],
                                  keys[pygame.K_DOWN], keys[pygame.K_UP])
        _, reward, terminated, truncated, info = env.step(action)
        episode_return += reward
        if terminated or truncated:
            print(f"episode return {episode_return:.0f}, discovery {info['discovery']}")
            env.reset()
            episode_return = 0.0
        frame = env.render()
    window.close()
    env.close()


if __name__ == "__main__":
    main()
