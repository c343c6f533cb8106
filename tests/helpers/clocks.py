"""Clocks for tests of code that reads two clocks."""


class SwitchingClocks:
    """A monotonic clock and a wall clock 900 s ahead of it, both reading ``now``; the first
    ``switches`` reads of the wall clock come after a thread switch of ``switch_s``."""

    def __init__(self, now: float, switch_s: float, switches: int = 1):
        self.now, self.switch_s, self.switches = now, switch_s, switches

    def monotonic(self) -> float:
        return self.now

    def wall(self) -> float:
        if self.switches > 0:
            self.switches -= 1
            self.now += self.switch_s
        return self.now + 900.0
