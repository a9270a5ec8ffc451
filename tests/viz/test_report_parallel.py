"""The report's figures drawn on two CPUs (a forked copy draws every second one) are the bytes
drawn one after another in this process, and a copy that fails leaves its figures to this one."""

from __future__ import annotations

import os

import numpy as np
import pytest

from usvlog.view import report as rp


def _figs(parent: int, fail_in_copy: bool = False):
    """Four small figures (one the log 'lacks'); with ``fail_in_copy`` the copy cannot draw."""
    plt = rp._plt()
    x = np.linspace(0.0, 10.0, 2000)

    def make(k):
        def draw():
            if fail_in_copy and os.getpid() != parent:
                raise RuntimeError("the copy fails")
            if k == 2:
                return None
            fig, ax = plt.subplots(figsize=(3.0, 2.0))
            ax.plot(x, np.sin(x * (k + 1)), label=f"sine {k}")
            ax.set_title(f"figure {k}")
            ax.legend()
            return fig
        return draw
    return [(f"f{k}.png", f"Figure {k}", make(k), "nothing") for k in range(4)]


@pytest.mark.parametrize("fail_in_copy", [False, True])
def test_two_cpus_draw_the_same_bytes(fail_in_copy):
    if not rp._two_cores():
        pytest.skip("drawing on two CPUs needs Linux, a second CPU and no other thread running")
    pid = os.getpid()
    one = [rp._drawn(title, make) for _name, title, make, _needs in _figs(pid)]
    two = rp.draw_all(_figs(pid, fail_in_copy))
    assert one[2] is None and two[2] is None
    assert [d is None for d in one] == [d is None for d in two]
    for a, b in zip(one, two):
        if a is not None:
            assert a[0] == b[0]                       # caption
            assert a[1] == b[1] and a[1][:8] == b"\x89PNG\r\n\x1a\n"   # the very same PNG bytes
