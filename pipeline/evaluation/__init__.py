"""Judging a method: converged Monte-Carlo references (reference), error metrics
(metrics), the budget sweep of ``prt evaluate`` (evaluate), its charts (charts) and the
independent Mitsuba 3 cross-check (mitsuba)."""
