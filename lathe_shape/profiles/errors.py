"""The error every profile reader and validator raises."""

from __future__ import annotations

__all__ = ["ProfileError"]


class ProfileError(ValueError):
    """Invalid profile input. The message names the source and the problem."""
