# SPDX-License-Identifier: GPL-3.0-or-later
"""Progress of a long operation (Bind, Bake Animation): Blender's own indicator in the status bar
and cursor (``WindowManager.progress_begin/update/end``), and the operation's whole time for its
report. Core functions take a :class:`Progress` (or None: no indicator), so scripts and tests run
them without a window and tests count the calls with a stand-in window manager.
"""
import time


class Progress:
    """``with Progress(wm, steps) as p: ... p.step(i)``; ``p.ms`` is the time since it began."""

    def __init__(self, wm=None, steps=1):
        self.wm = wm
        self.steps = max(1, int(steps))
        self.t0 = time.perf_counter()
        self.done = 0
        self._open = False

    def begin(self, steps=None):
        if steps is not None:
            self.steps = max(1, int(steps))
        self.t0 = time.perf_counter()
        if self.wm is not None and not self._open:
            self.wm.progress_begin(0, self.steps)
            self._open = True
        return self

    def step(self, done=None):
        self.done = self.done + 1 if done is None else int(done)
        if self._open:
            self.wm.progress_update(min(self.done, self.steps))

    def end(self):
        if self._open:
            self.wm.progress_end()
            self._open = False

    @property
    def ms(self):
        return (time.perf_counter() - self.t0) * 1e3

    def __enter__(self):
        return self.begin()

    def __exit__(self, *exc):
        self.end()
        return False


def progress(progress_or_none, steps=1):
    """The caller's Progress (its step count set), or a silent one."""
    p = progress_or_none if progress_or_none is not None else Progress(None, steps)
    p.steps = max(1, int(steps))
    return p
