"""Published algorithms reproduced as written, to compare kincal against. See ``kincal.baselines.thesis``."""

from kincal.baselines import thesis

__all__ = ["thesis"]
