"""Exact emulations of servo-chip filters, their legal parameter ranges, profiles and exports."""

from servogym.chips._space import ParameterError, ParameterSpace, ParamSpec

__all__ = ["ParamSpec", "ParameterError", "ParameterSpace"]
