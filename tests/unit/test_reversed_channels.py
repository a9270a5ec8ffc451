"""A vessel with a reversed thruster channel (reversed_right): every place that turns commands into
forces or forces into commands says which thruster a command is for, so a reversed channel is a
round trip (simulated forces -> recorded commands -> import -> the same forces), never a ConfigError.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from usvlog.io.importers.core import Assembler, ImportReport
from usvlog.model.vessel import Thrusters, default_vessel
from usvlog.sim.simulate import SimSettings, simulate
from usvlog.view import data as vd


def _vessel():
    v = default_vessel()
    return replace(v, thrusters=Thrusters(arm_m=v.thrusters.arm_m, map="linear", forward_n=30.0, reverse_n=20.0,
                                          reversed_right=True))


def test_simulated_commands_of_a_reversed_channel_map_back_to_the_forces():
    vessel = _vessel()
    log = simulate("turns", SimSettings(vessel=vessel, duration_s=30.0), seed=1)
    th = log["/thrust/command"]
    fl, fr = th["thrust_left_n"].to_numpy(), th["thrust_right_n"].to_numpy()
    # the recorded right command has the opposite sign of its force (the channel is reversed)
    moving = np.abs(fr) > 0.1
    assert moving.any() and np.all(np.sign(th["right"].to_numpy()[moving]) == -np.sign(fr[moving]))
    # the view's forces from the commands alone are the simulated ones
    bare = log.copy(deep=True)
    bare["/thrust/command"]["thrust_left_n"] = np.nan
    bare["/thrust/command"]["thrust_right_n"] = np.nan
    t, tu, tr = vd.recorded_tau(bare)
    tu0, tr0 = vessel.thrusters.tau_from_forces(fl, fr)
    np.testing.assert_allclose(tu, tu0, atol=0.05)
    np.testing.assert_allclose(tr, tr0, atol=0.05)


def test_import_turns_reversed_normalized_commands_into_the_right_forces():
    vessel = _vessel()
    rep = ImportReport(source="x", format="csv")
    asm = Assembler(rep, vessel=vessel, thrust_unit="normalized")
    n = 600
    t = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 10_000_000
    left = np.full(n, 0.5)
    right = np.full(n, -0.5)           # the reversed channel: -0.5 drives it forward
    out = asm.process({"thrust": {"t_ns": t, "left": left, "right": right,
                                  "unit": np.full(n, "normalized", dtype=object)}})
    out.update(asm.finish())
    f = out["/thrust/command"]
    np.testing.assert_allclose(f["thrust_left_n"], 15.0)
    np.testing.assert_allclose(f["thrust_right_n"], 15.0)
