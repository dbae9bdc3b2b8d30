"""Errors of the kinematics package."""

from __future__ import annotations


class KinematicsError(ValueError):
    """Base class: a pose or move the machine cannot take."""


class UnreachableDirection(KinematicsError):
    """A build direction that no A within the limits turns to machine +Z."""
