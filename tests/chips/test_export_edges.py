"""Export details the mutation run found unpinned (docs/chips/pmd-export.md)."""

from __future__ import annotations

import dataclasses

import pytest

from servogym.chips import ParameterError
from servogym.chips.pmd import PMDParams
from servogym.chips.pmd._export import HostCommand, from_cmotion, to_cmotion


def test_cmotion_error_lines_count_a_leading_blank_line():
    # A Navigator snippet read as a Magellan one fails on its first call: line 1, or line 2
    # once a blank line precedes it (lines are counted from the start of the text).
    text = to_cmotion(PMDParams(model="MC2800"))
    body = "\n".join(line for line in text.splitlines() if line.startswith("PMD"))
    with pytest.raises(ParameterError, match=r"line 1: unknown C-Motion call PMDSetKp\(\)"):
        from_cmotion(body, model="MC58000")
    with pytest.raises(ParameterError, match=r"line 2: unknown C-Motion call PMDSetKp\(\)"):
        from_cmotion("\n" + body, model="MC58000")


def test_host_commands_are_frozen():
    cmd = HostCommand(opcode=0x05, name="SetKp", axis=1, data=(100,))
    with pytest.raises(dataclasses.FrozenInstanceError):
        cmd.axis = 2
