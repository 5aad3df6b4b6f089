"""Preset systems. ``macro()`` is the paper's example (section 6)."""

from sdjls_gym.systems.macro import macro

PRESETS = {"macro": macro}

__all__ = ["macro", "PRESETS"]
