"""A pygame window for ``render_mode="human"`` and ``python -m bbs.play`` (extra ``play``)."""

import importlib.util

import numpy as np

PYGAME_MISSING = ("render_mode='human' and `python -m bbs.play` need pygame, which is optional: "
                  "pip install 'vsgjax[play]' (or pip install pygame)")


def pygame_available() -> bool:
    """Whether pygame is installed (found without importing it: no banner, no start-up cost)."""
    return importlib.util.find_spec("pygame") is not None


def import_pygame():
    try:
        import pygame
    except ImportError as error:
        raise ImportError(PYGAME_MISSING) from error
    return pygame


class Window:
    def __init__(self, title: str, width: int, height: int):
        self.pygame = import_pygame()
        self.pygame.display.init()  # display only: no audio device needed
        self.pygame.display.set_caption(title)
        self.screen = self.pygame.display.set_mode((width, height))
        self.clock = self.pygame.time.Clock()
        self.closed = False

    def show(self, image: np.ndarray, fps: float) -> None:
        """Blit an RGB image [H, W, 3] and wait to keep ``fps``; records if the user closed it."""
        if self.pygame.event.get(self.pygame.QUIT):
            self.closed = True
        surface = self.pygame.surfarray.make_surface(np.ascontiguousarray(image.swapaxes(0, 1)))
        self.screen.blit(surface, (0, 0))
        self.pygame.display.flip()
        self.clock.tick(fps)

    def close(self) -> None:
        self.pygame.display.quit()
