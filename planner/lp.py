"""Linear programs through HiGHS (highspy): the one LP back end of the grip models.

`planner.closure.min_grip_force`, `planner.grip`'s capacity and demand programs and the
controller's force balance all solve small dense programs here. `solve_highs` separates
"infeasible" (None) from "the solver failed" (PlannerError); `highs_lp` is one solve with
``scipy.optimize.linprog``'s status codes; `solve_highs_rhs` re-solves the program solved last
with other equality right-hand sides from its optimal basis (the grip force of one set of
contacts under each gravity direction).
"""

from __future__ import annotations

import os
import sys

import numpy as np

from planner.errors import PlannerError

def solve_highs(c, A_ub, b_ub, A_eq, b_eq, bounds, what: str, detail: str = "; the answer is unknown"):
    """Solve ``min c x`` s.t. ``A_ub x <= b_ub``, ``A_eq x = b_eq``, ``bounds`` with HiGHS, for
    a program that cannot be unbounded: the result (``.x``) at an optimum, None when it is
    infeasible.

    HiGHS's "unbounded or infeasible" (e.g. from presolve) means infeasible here. When the
    default method ends unsure (e.g. "model_status is Unknown; primal_status is Infeasible",
    seen on a synthesized Allegro grasp) the interior-point method decides.

    Raises:
        PlannerError: any other status (iteration limit, numerical trouble): the answer is
            unknown, which is neither a value nor infeasible.
    """
    res = None
    for method in ("highs", "highs-ipm"):
        res = highs_lp(c, A_ub, b_ub, A_eq, b_eq, bounds, method)
        if res.status == 0:
            return res
        if res.status == 2 or (res.status == 4 and "unbounded or infeasible" in res.message):
            return None
    raise PlannerError(f"{what} failed (HiGHS status {res.status}: {res.message}){detail}")


class LPResult:
    """What `highs_lp` answers, in ``scipy.optimize.linprog``'s terms: ``status`` (0 optimal,
    1 iteration or time limit, 2 infeasible, 3 unbounded, 4 other), ``message``, ``x``."""

    __slots__ = ("status", "message", "x")

    def __init__(self, status: int, message: str, x):
        self.status, self.message, self.x = status, message, x


_HIGHS = None  # one highspy.Highs per process, reused (a model is passed per solve)
#: The key `solve_highs_rhs` gave the program the shared Highs holds at an optimum (None: no
#: program, or one passed by any other solve): a program with this key differs only in b_eq.
_HELD = None
_SIMPLEX = False  # the last program passed was solved by the simplex (it has an optimal basis)


def _highs():
    global _HIGHS
    if _HIGHS is None:
        import highspy  # deferred: loaded (and its banner silenced) at the first solve

        # its constructor prints a banner on the C stdout: keep a command's output clean
        sys.stdout.flush()
        saved = os.dup(1)
        try:
            with open(os.devnull, "w") as null:
                os.dup2(null.fileno(), 1)
                h = highspy.Highs()
        finally:
            os.dup2(saved, 1)
            os.close(saved)
        h.setOptionValue("output_flag", False)
        # the programs are small and dense: presolve costs more than it saves (0.54 vs
        # 0.91 ms per grip LP, the same optimum)
        h.setOptionValue("presolve", "off")
        # no worker threads: the verification replays fork this process (a fork of a process
        # with live threads can deadlock), and the programs are too small to share
        h.setOptionValue("threads", 1)
        _HIGHS = (highspy, h)
    return _HIGHS


def highs_lp(c, A_ub, b_ub, A_eq, b_eq, bounds, method: str) -> LPResult:
    """One HiGHS solve through highspy, the HiGHS project's own Python interface (a model
    passed as arrays: scipy's linprog spends 2-3x HiGHS's own time in checking and
    converting its input on the planner's small programs)."""
    global _HELD, _SIMPLEX
    highspy, h = _highs()
    _HELD, _SIMPLEX = None, method != "highs-ipm"
    inf = highspy.kHighsInf
    c = np.asarray(c, dtype=float)
    n = len(c)
    A_ub = np.zeros((0, n)) if A_ub is None or not len(A_ub) else np.asarray(A_ub, dtype=float)
    b_ub = np.zeros(0) if not len(A_ub) else np.asarray(b_ub, dtype=float)
    A_eq, b_eq = np.asarray(A_eq, dtype=float), np.asarray(b_eq, dtype=float)
    A = np.vstack([A_eq, A_ub])
    cols, rows = np.nonzero(A.T)  # column-major order of the non-zeros
    start = np.zeros(n + 1, dtype=np.int32)
    np.cumsum(np.bincount(cols, minlength=n), out=start[1:])
    lo = np.array([-inf if b[0] is None else b[0] for b in bounds], dtype=float)
    hi = np.array([inf if b[1] is None else b[1] for b in bounds], dtype=float)
    lp = highspy.HighsLp()
    lp.num_col_, lp.num_row_ = n, len(A)
    lp.col_cost_, lp.col_lower_, lp.col_upper_ = c, lo, hi
    lp.row_lower_ = np.r_[b_eq, np.full(len(b_ub), -inf)]
    lp.row_upper_ = np.r_[b_eq, b_ub]
    lp.a_matrix_.format_ = highspy.MatrixFormat.kColwise
    lp.a_matrix_.start_, lp.a_matrix_.index_, lp.a_matrix_.value_ = start, rows.astype(np.int32), A[rows, cols]
    h.setOptionValue("solver", "ipm" if method == "highs-ipm" else "choose")
    h.passModel(lp)
    h.run()
    st = h.getModelStatus()
    S = highspy.HighsModelStatus
    if st == S.kOptimal:
        return LPResult(0, "Optimal", np.array(h.getSolution().col_value, dtype=float))
    if st == S.kInfeasible:
        return LPResult(2, "The problem is infeasible.", None)
    if st == S.kUnboundedOrInfeasible:
        return LPResult(4, "The problem is unbounded or infeasible.", None)
    if st == S.kUnbounded:
        return LPResult(3, "The problem is unbounded.", None)
    if st in (S.kIterationLimit, S.kTimeLimit):
        return LPResult(1, f"model_status is {h.modelStatusToString(st)}", None)
    return LPResult(4, f"model_status is {h.modelStatusToString(st)}", None)


def solve_highs_rhs(key, b_eq, build, what: str, detail: str = "; the answer is unknown"):
    """`solve_highs`, for a family of programs that differ only in ``b_eq`` and share ``key``
    (hashable; the caller's promise that ``build()``, which returns the rest of the program
    ``(c, A_ub, b_ub, A_eq, bounds)``, is the same for every member; it is called only when the
    program is solved from scratch): when the shared HiGHS instance holds the last program of
    this family at an optimum, only the equality rows' bounds change and HiGHS's simplex goes
    on from that optimal basis (a few iterations instead of a solve from scratch, and no model
    passed). Anything else (another program solved in between, a warm solve ending infeasible
    or unsure) solves from scratch through `solve_highs`, which decides "infeasible" or raises
    as it does.

    Returns:
        The objective value at an optimum (not the solution), None when the program is
        infeasible.
    """
    global _HELD
    highspy, h = _highs()
    if _HELD is not None and _HELD == key:
        b = np.asarray(b_eq, dtype=float)  # `highs_lp` passes the equality rows first
        h.changeRowsBounds(len(b), _rows(len(b)), b, b)
        h.run()
        if h.getModelStatus() == highspy.HighsModelStatus.kOptimal:
            return float(h.getObjectiveValue())
        _HELD = None  # infeasible or unsure from the warm basis: the solve from scratch decides
    c, A_ub, b_ub, A_eq, bounds = build()
    res = solve_highs(c, A_ub, b_ub, A_eq, b_eq, bounds, what, detail)
    if res is None:
        return None
    # held only after the default method (simplex): an interior-point answer has no basis to go on from
    _HELD = key if _SIMPLEX else None
    return float(np.dot(c, res.x))


_ROWS: dict[int, np.ndarray] = {}


def _rows(n: int) -> np.ndarray:
    """The row indices 0..n-1 as HiGHS takes them (made once per n)."""
    r = _ROWS.get(n)
    if r is None:
        r = _ROWS[n] = np.arange(n, dtype=np.int32)
        r.setflags(write=False)
    return r


def forget() -> None:
    """Forget the program the shared HiGHS instance holds (the next `solve_highs_rhs` solves
    from scratch): for tests that stand in for the solver or compare with answers from scratch."""
    global _HELD
    _HELD = None
