"""Run ``mireg register`` on a Ray cluster: one task per log (``run``), or one long log split into
overlapping segments registered in parallel and stitched (``segments``).

Ray does the scheduling, the retries on lost workers, the resource accounting and the dashboard;
this package only says what to run and keeps a manifest of what is done. See docs/RAY.md.
"""

__version__ = "0.1.0"
