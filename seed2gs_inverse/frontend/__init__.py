"""The 2D front end: it supplies the seed mask m* and the supervision masks Y(c)."""

from .base import Candidate, Grounder, Tracker

__all__ = ["Candidate", "Grounder", "Tracker"]
