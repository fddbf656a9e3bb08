"""Option types and helpers shared by the `bgc` commands (click's side of the CLI)."""
from __future__ import annotations

import math

import click

from bgc.base.outfiles import Inputs
from bgc.base.reach import reached_files


class LazyChoice(click.Choice):
    """click's Choice whose choices come from ``load()`` on first use (they live in a module
    that listing the commands, ``bgc --help``, should not import)."""

    def __init__(self, load, case_sensitive: bool = True):
        self._load, self._choices = load, None
        super().__init__((), case_sensitive)

    @property
    def choices(self):
        if self._choices is None:
            self._choices = tuple(self._load())
        return self._choices

    @choices.setter
    def choices(self, value):  # click's __init__ sets them: they come from load instead
        if value:
            self._choices = tuple(value)


class _Finite(click.ParamType):
    """A finite float in a range: click's FloatRange lets inf and nan through."""

    name = "float"

    def __init__(self, lo=None, hi=None, lo_open=False, hi_open=False):
        self.lo, self.hi, self.lo_open, self.hi_open = lo, hi, lo_open, hi_open

    def _range(self) -> str:
        lo = "" if self.lo is None else f"{self.lo:g} {'<' if self.lo_open else '<='} "
        hi = "" if self.hi is None else f" {'<' if self.hi_open else '<='} {self.hi:g}"
        return f"{lo}x{hi}"

    def convert(self, value, param, ctx):
        shown = repr(value) if len(repr(value)) <= 40 else repr(value)[:37] + "..."
        if isinstance(value, float):
            v = value
        else:
            try:
                v = float(str(value).strip())
            except ValueError:
                self.fail(f"{shown} is not a number", param, ctx)
        if not math.isfinite(v):
            self.fail(f"{shown} is not a finite number", param, ctx)
        if self.lo is not None and (v <= self.lo if self.lo_open else v < self.lo) or \
                self.hi is not None and (v >= self.hi if self.hi_open else v > self.hi):
            self.fail(f"{shown} is not in the range {self._range()}", param, ctx)
        return v


def finite(lo=None, hi=None, lo_open=False, hi_open=False) -> _Finite:
    return _Finite(lo, hi, lo_open, hi_open)


POSITIVE = finite(0.0, lo_open=True)
RTOL = finite(0.0, 1.0, lo_open=True, hi_open=True)


def model_inputs(*paths, follow: bool = True):
    """The inputs of this run that no output may replace: the given files (models, scenes)
    and, with ``follow``, the files the models import and the tables they and the scenes read (only once bgc's parser has read them:
    the imports are found by reading the files again)."""
    ins = Inputs()
    for p in paths:
        if p is None:
            continue
        ins.add(p)
        for f in reached_files(p, partial=True) or () if follow else ():
            ins.add(f.path)  # its imports and tables (bounded reads)
    return ins
