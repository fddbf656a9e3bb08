"""Stage 3: causality by the sequential causality assignment procedure (SCAP).

A pure graph pass over element and bond ids, no symbolic work (as in ModelingToolkit's
structural passes). The result says, for every bond, which end computes its *effort* (the other
end computes its flow); the causal stroke sits at the end that receives the effort.

Order (Karnopp, Margolis & Rosenberg): 1. sources and fixed-form R elements, each followed by
propagation through 0/1 junctions, TF/MTF and GY/MGY; 2. storage elements in integral causality,
with propagation; 3. remaining R elements (resistance form), with propagation; 4. any bond still
open (zero-order loops between junctions). Storage elements that propagation forces into
derivative causality are reported with the decision that forced them.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from bgc.base.errors import ModelError
from bgc.core.graph import BondGraph, FlatBond, FlatElement

FIXED_R = {"effort": "resistance", "flow": "conductance"}


@dataclass(frozen=True)
class Causality:
    effort_by: dict  # bond id -> element id that computes the bond's effort
    derivative: tuple[str, ...]  # storage elements left in derivative causality
    forced_by: dict  # element id -> (origin element id, via junction id) for derivative ones
    arbitrary: tuple[str, ...]  # R elements whose causality SCAP chose (step 3)
    open_bonds: tuple[str, ...]  # bonds chosen in step 4
    warnings: tuple[str, ...]
    #: zero-flow (or driven) sources that close a kinematic loop or lock part of a multibond,
    #: turned into constraints: causally effort sources whose effort is an unknown reaction
    #: (bgc.core.constraints); in the order they were chosen
    constraints: tuple[str, ...] = ()

    def sets_effort(self, bond: FlatBond, el: str) -> bool:
        return self.effort_by[bond.id] == el

    def form(self, bg: BondGraph, el: FlatElement) -> str:
        """The causal form of an element, in words."""
        t = el.type
        bonds = bg.bonds_of(el.id)
        if t in ("I", "C"):
            sets = self.effort_by[bonds[0].id] == el.id
            integral = (not sets) if t == "I" else sets
            return "integral" if integral else "derivative"
        if t == "R":
            return "resistance" if self.effort_by[bonds[0].id] == el.id else "conductance"
        if t in ("TF", "MTF"):
            b_in = next(b for b in bonds if b.dst == el.id)
            return "flow forward" if self.effort_by[b_in.id] == el.id else "effort forward"
        if t == "Sf" and el.id in self.constraints:
            return "constraint (reaction effort)"
        if t in ("GY", "MGY"):
            return ("flows in" if all(self.effort_by[b.id] == el.id for b in bonds)
                    else "efforts in")
        if t == "0":
            b = next(b for b in bonds if self.effort_by[b.id] != el.id)
            return f"effort from {b.id}"
        if t == "1":
            b = next(b for b in bonds if self.effort_by[b.id] == el.id)
            return f"flow from {b.id}"
        return "fixed"


class CausalConflict(ModelError):
    """A causal conflict, with the element where it arose (``at``)."""

    def __init__(self, coord, message: str, at: str, origins: tuple = ()):
        super().__init__(coord, message)
        self.at = at
        self.origins = origins  # the elements whose decisions clash


class _Scap:
    def __init__(self, bg: BondGraph):
        self.bg = bg
        self.effort_by: dict[str, str] = {}
        self.origin: dict[str, tuple[str, str]] = {}  # bond -> (origin element, via element)

    def other(self, b: FlatBond, el: str) -> str:
        return b.dst if b.src == el else b.src

    def set(self, b: FlatBond, setter: str, origin: str, via: str, queue: deque) -> None:
        cur = self.effort_by.get(b.id)
        if cur is not None:
            if cur != setter:
                # Both ends impose the same variable on the bond: `via` its effort if it is to
                # set the effort (else its flow), and the owner so far from the other end.
                o, o_via = self.origin[b.id]
                what = "effort" if setter == via else "flow"
                src = lambda x, y: (self.kind(x) if x == y  # noqa: E731
                                    else f"{self.kind(x)} (through {self.kind(y)})")
                raise CausalConflict(self.bg.element(via).coord,
                                 f"causal conflict on bond {b.id!r} ({b.src} -> {b.dst}): "
                                 f"{src(origin, via)} and {src(o, o_via)} both impose its {what}",
                                 via, (origin, o))
            return
        self.effort_by[b.id] = setter
        self.origin[b.id] = (origin, via)
        queue.append(b.src)
        queue.append(b.dst)

    def kind(self, eid: str) -> str:
        el = self.bg.element(eid)
        t = el.type
        return f"{t}-junction {eid!r}" if t in ("0", "1") else f"{t} {eid!r}"

    def propagate(self, queue: deque, origin: str) -> None:
        while queue:
            eid = queue.popleft()
            el = self.bg.element(eid)
            t = el.type
            bonds = self.bg.bonds_of(eid)
            if t in ("0", "1"):
                # "imposing" bonds: on a 0-junction those where the other end sets the effort;
                # on a 1-junction those where the junction sets the effort (the other end sets
                # the flow). Exactly one imposing bond per junction.
                def imposing(b):
                    eb = self.effort_by.get(b.id)
                    if eb is None:
                        return None
                    return (eb != eid) if t == "0" else (eb == eid)

                states = [imposing(b) for b in bonds]
                n_imp = sum(1 for s in states if s is True)
                if n_imp > 1:
                    imp = [b for b, s in zip(bonds, states) if s]
                    origins = sorted({self.origin[b.id][0] for b in imp})
                    what = "effort" if t == "0" else "flow"
                    who = (f"{' and '.join(self.kind(o) for o in origins)} each impose its "
                           f"{what}" if len(origins) > 1 else
                           f"{self.kind(origins[0])} imposes its {what} through {len(imp)} "
                           "bonds")
                    raise CausalConflict(el.coord, f"causal conflict at {self.kind(eid)}: "
                                                   f"{who}", eid, tuple(origins))
                if n_imp == 0 and bonds and all(st is False for st in states):
                    what = "effort" if t == "0" else "flow"
                    raise CausalConflict(el.coord, f"causal conflict at {self.kind(eid)}: every "
                                                   f"bond has its "
                                                   f"{'flow' if t == '0' else 'effort'} imposed "
                                                   f"and none sets its {what}", eid)
                if n_imp == 1:
                    for b, s in zip(bonds, states):
                        if s is None:  # not imposing: on a 0 the junction sets the effort
                            self.set(b, eid if t == "0" else self.other(b, eid),
                                     origin, eid, queue)
                elif states.count(None) == 1:
                    b = bonds[states.index(None)]
                    self.set(b, self.other(b, eid) if t == "0" else eid,
                             origin, eid, queue)
            elif t in ("TF", "MTF"):
                a, b = bonds
                ea, eb = self.effort_by.get(a.id), self.effort_by.get(b.id)
                if ea is not None and eb is None:
                    self.set(b, self.other(b, eid) if ea == eid else eid, origin, eid, queue)
                elif eb is not None and ea is None:
                    self.set(a, self.other(a, eid) if eb == eid else eid, origin, eid, queue)
                elif ea is not None and eb is not None and (ea == eid) == (eb == eid):
                    raise CausalConflict(el.coord, f"causal conflict at {self.kind(eid)}: it must "
                                                   "set the effort on exactly one of its bonds",
                                                   eid)
            elif t in ("GY", "MGY"):
                a, b = bonds
                ea, eb = self.effort_by.get(a.id), self.effort_by.get(b.id)
                if ea is not None and eb is None:
                    self.set(b, eid if ea == eid else self.other(b, eid), origin, eid, queue)
                elif eb is not None and ea is None:
                    self.set(a, eid if eb == eid else self.other(a, eid), origin, eid, queue)
                elif ea is not None and eb is not None and (ea == eid) != (eb == eid):
                    raise CausalConflict(el.coord, f"causal conflict at {self.kind(eid)}: it sets "
                                                   "both efforts or both flows", eid)

    def decide(self, el: FlatElement, sets_effort: bool) -> None:
        (b,) = self.bg.bonds_of(el.id)
        q: deque = deque()
        self.set(b, el.id if sets_effort else self.other(b, el.id), el.id, el.id, q)
        self.propagate(q, el.id)


class _Constrain(Exception):
    """SCAP met a conflict that a flow source resolves by becoming a constraint."""

    def __init__(self, source: str):
        super().__init__(source)
        self.source = source


def assign_causality(bg: BondGraph, allow_derivative: bool = False) -> Causality:
    """SCAP; a closed kinematic loop or a partly determined multibond turns the flow source
    that closes it into a constraint (one at a time, SCAP again after each), so models that
    compile without constraints get exactly the causality they always had."""
    constraints: tuple[str, ...] = ()
    while True:
        try:
            return _assign(bg, allow_derivative, constraints)
        except _Constrain as c:
            constraints = constraints + (c.source,)


def _assign(bg: BondGraph, allow_derivative: bool, constraints: tuple) -> Causality:
    s = _Scap(bg)
    try:
        _sources(s, constraints)
    except CausalConflict:
        # the sources alone conflict. Where their flows went through a non-square modulus
        # from its small side (a lock's 2 components taken for 3: a closed chain of locks
        # then meets itself), that lock is a constraint first (the partly determined rule)
        closing = _partial_open(bg, s, constraints)
        if closing is not None:
            raise _Constrain(closing) from None
        raise
    base = _copy(s)
    # 2. storage in integral causality. In file order when that leaves none in derivative
    # causality (then the order does not matter); otherwise the independent set is chosen.
    trial = _copy(s)
    plain_err = None
    try:
        arbitrary, open_bonds = _finish(trial, [e for e in bg.elements if e.type in ("I", "C")])
        plain_ok = not _derivative(bg, trial)
    except ModelError as err:
        plain_ok, plain_err = False, err
    if plain_ok:
        s = trial
    else:
        try:
            _choose_independent(bg, s)
            arbitrary, open_bonds = _finish(s, [])
        except CausalConflict as err:
            loop = closed_loop(bg, err.at)
            closing = _closing_source(bg, loop, constraints)
            if closing is None and plain_err is None:  # a lock the plain order left partial
                closing = _partial_in(bg, trial, constraints)
            if closing is None:  # a lock the sources left partial (a closed chain of locks)
                closing = _partial_open(bg, base, constraints)
            if closing is not None:
                raise _Constrain(closing) from None
            if loop:
                coord, message, advice = closed_loop_error(bg, loop, err.message)
                raise ModelError(coord or err.coord, message, advice) from None
            if plain_err is not None:
                raise plain_err from None
            raise
        except ModelError:
            if plain_err is not None:
                raise plain_err from None
            raise
    _check_partial(bg, s, constraints)
    # Derivative causality
    derivative, forced = [], {}
    for el in bg.elements:
        if el.type in ("I", "C"):
            (b,) = bg.bonds_of(el.id)
            sets = s.effort_by[b.id] == el.id
            if sets == (el.type == "I"):
                derivative.append(el.id)
                forced[el.id] = s.origin[b.id]
    warnings = []
    if arbitrary:
        warnings.append("R elements with causality chosen by SCAP (possible algebraic loop): "
                        + ", ".join(arbitrary))
    if open_bonds:
        warnings.append("bonds with arbitrary causality (zero-order causal paths): "
                        + ", ".join(open_bonds))
    caus = Causality(dict(s.effort_by), tuple(derivative), forced, tuple(arbitrary),
                     tuple(open_bonds), tuple(warnings), tuple(constraints))
    if derivative and not allow_derivative:
        culprit = fixed_r_culprit(bg, caus)
        if culprit is not None:
            raise ModelError(culprit[0], culprit[1])
        raise ModelError(bg.element(derivative[0]).coord, derivative_message(bg, caus))
    return caus


def _sources(s: _Scap, constraints: tuple) -> None:
    """SCAP's step 1: sources and R elements whose law fixes their form, each followed by
    propagation; a constraint sets its effort."""
    for el in s.bg.elements:
        if el.type == "Se" or (el.type == "Sf" and el.id in constraints):
            s.decide(el, True)
        elif el.type == "Sf":
            s.decide(el, False)
        elif el.type == "R" and el.law and el.law[0] in FIXED_R:
            s.decide(el, el.law[0] == "effort")


def _copy(s: _Scap) -> _Scap:
    c = _Scap(s.bg)
    c.effort_by = dict(s.effort_by)
    c.origin = dict(s.origin)
    return c


def _finish(s: _Scap, storage) -> tuple[list, list]:
    """SCAP from step 2 on: the given storage elements in order, then R, then open bonds."""
    bg = s.bg
    for el in storage:
        if bg.bonds_of(el.id)[0].id not in s.effort_by:
            s.decide(el, el.type == "C")
    # 3. remaining R elements: resistance form
    arbitrary = []
    for el in bg.elements:
        if el.type == "R" and bg.bonds_of(el.id)[0].id not in s.effort_by:
            arbitrary.append(el.id)
            s.decide(el, True)
    # 4. open bonds (zero-order loops): the bond's source end sets the effort
    open_bonds = []
    for b in bg.bonds:
        if b.id not in s.effort_by:
            open_bonds.append(b.id)
            q: deque = deque()
            s.set(b, b.src, b.src, b.src, q)
            s.propagate(q, b.src)
    return arbitrary, open_bonds


def _derivative(bg: BondGraph, s: _Scap) -> list:
    out = []
    for el in bg.elements:
        if el.type in ("I", "C"):
            (b,) = bg.bonds_of(el.id)
            if (s.effort_by.get(b.id) == el.id) == (el.type == "I"):
                out.append(el.id)
    return out


#: Cost of a two-port in its non-preferred causality, by the modulus it must invert.
INVERT_COST = {"MTF": 10, "MGY": 10, "TF": 1, "GY": 1}
NONSQUARE_COST = 1000


def _inversions(bg: BondGraph, s: _Scap) -> int:
    """How much inverting a complete causal assignment asks: a modulated (state- or
    time-dependent) modulus can vanish during the motion, a constant one cannot, and a
    non-square one has no inverse at all."""
    cost = 0
    for el in bg.elements:
        if el.type not in INVERT_COST:
            continue
        b1, b2 = sorted(bg.bonds_of(el.id), key=lambda b: b.dst != el.id)
        if el.type in ("TF", "MTF"):
            inverted = s.effort_by[b1.id] != el.id
        else:
            inverted = not (s.effort_by[b1.id] == el.id and s.effort_by[b2.id] == el.id)
        if inverted:
            cost += NONSQUARE_COST if b1.n != b2.n else INVERT_COST[el.type]
    return cost


def _choose_independent(bg: BondGraph, s: _Scap) -> None:
    """Give integral causality to storage elements one at a time, each time the first (by
    instance path, so the file's order does not matter) whose choice, completed by SCAP,
    inverts the cheapest moduli (``_inversions``): the dependent elements are then those
    reached through modulated or non-square moduli, and the map from the independent states
    to them stays regular. Ties (e.g. equal inertias on one shaft) go to the first path."""
    storage = sorted((e for e in bg.elements if e.type in ("I", "C")), key=lambda e: e.id)
    while True:
        cands = [e for e in storage if bg.bonds_of(e.id)[0].id not in s.effort_by]
        if not cands:
            return
        best, best_score = None, None
        for el in cands:
            t = _copy(s)
            try:
                t.decide(el, el.type == "C")
                _finish(t, [e for e in cands if e is not el])
                score = (0, _inversions(bg, t), len(_derivative(bg, t)))
            except ModelError:
                score = (1, 0, 0)
            if best_score is None or score < best_score:
                best, best_score = el, score
            if score[:2] == (0, 0):
                break  # nothing inverted: cannot do better
        s.decide(best, best.type == "C")


def _closing_source(bg: BondGraph, loop: list, constraints: tuple) -> str | None:
    """The flow source that becomes the loop's constraint: a fixed one (its flow a constant:
    a pivot, not a drive) before a driven one, then the last one written on the loop (the
    first is the loop's anchor, as a user reads it), never one that is already, nor one that
    cannot be (``_can_close``)."""
    order = {e.id: i for i, e in enumerate(bg.elements)}
    srcs = [x for x in loop if x != "ground" and bg.element(x).type == "Sf"
            and x not in constraints]
    fixed = [x for x in srcs if not bg.element(x).law[1].names()]
    ranked = sorted(fixed, key=order.get, reverse=True) + \
        sorted((x for x in srcs if x not in fixed), key=order.get, reverse=True)
    return next((x for x in ranked if _can_close(bg, x, constraints)), None)


def _can_close(bg: BondGraph, source: str, constraints: tuple) -> bool:
    """Whether ``source`` can be a constraint beside ``constraints``: as an effort source its
    effort must not clash, in SCAP's step 1, with another's (a ground whose lock is already a
    constraint: the two would both set the lock's 0-junction's effort)."""
    try:
        _sources(_Scap(bg), constraints + (source,))
    except CausalConflict as err:
        return source not in err.origins
    return True


def _partial_source(bg: BondGraph, s: _Scap, bond: FlatBond, constraints: tuple) -> str | None:
    """The flow source whose imposed flow reached a non-square modulus from its small side."""
    origin = s.origin.get(bond.id, (None, None))[0]
    if origin is not None and bg.element(origin).type == "Sf" and origin not in constraints:
        return origin
    return None


def _partial_open(bg: BondGraph, s: _Scap, constraints: tuple) -> str | None:
    """``_check_partial``'s source on an unfinished assignment: the first non-square modulus
    (in element order) whose two bonds are set and which is inverted, if a flow source's
    imposed flow reached it from its small side."""
    for el in bg.elements:
        if el.type not in ("MTF", "MGY"):
            continue
        b1, b2 = sorted(bg.bonds_of(el.id), key=lambda b: b.dst != el.id)
        e1, e2 = s.effort_by.get(b1.id), s.effort_by.get(b2.id)
        if b1.n == b2.n or e1 is None or e2 is None:
            continue
        inv = e1 != el.id if el.type == "MTF" else not (e1 == el.id and e2 == el.id)
        if inv:
            src = _partial_source(bg, s, b1 if b1.n < b2.n else b2, constraints)
            if src is not None:
                return src
    return None


def _partial_in(bg: BondGraph, s: _Scap, constraints: tuple) -> str | None:
    """The flow source behind a non-square modulus that ``s`` leaves inverted, if any."""
    try:
        _check_partial(bg, s, constraints)
    except _Constrain as c:
        return c.source
    except ModelError:
        return None
    return None


def _check_partial(bg: BondGraph, s: _Scap, constraints: tuple = ()) -> None:
    for el in bg.elements:  # a non-square modulus left inverted: partly determined
        if el.type in ("MTF", "MGY"):
            b1, b2 = sorted(bg.bonds_of(el.id), key=lambda b: b.dst != el.id)
            inv = (s.effort_by[b1.id] != el.id if el.type == "MTF" else
                   not (s.effort_by[b1.id] == el.id and s.effort_by[b2.id] == el.id))
            if inv and b1.n != b2.n:
                small = b1 if b1.n < b2.n else b2
                src = _partial_source(bg, s, small, constraints)
                if src is not None:
                    raise _Constrain(src)
                big = b1 if b1.n > b2.n else b2
                why = (f"multibond {big.id!r} ({big.src} -> {big.dst}, n={big.n}) is only "
                       f"partly determined: causality reaches {el.type} {el.id!r} from its "
                       f"n={big.n} side, and its {b2.n}x{b1.n} modulus has no inverse "
                       f"(some components of {big.id!r} are dependent, some not)")
                raise ModelError(el.coord, why + ": split the multibond (give the free "
                                 "components their own storage element), or make a "
                                 "connection on its causal path compliant (a C || R coupling "
                                 "with a stiffness)")


def closed_loop(bg: BondGraph, at: str, avoid=frozenset()) -> list[str]:
    """A cycle through element ``at`` and the ground (every flow source joined to one ground
    node: fixed points are one body), made of two node-disjoint paths from ``at`` to the
    ground: a closed kinematic loop. Empty when there is none (or no inertia at all).
    ``avoid``: elements the cycle may not pass through."""
    import networkx as nx

    g = nx.Graph()
    for b in bg.bonds:
        if b.src not in avoid and b.dst not in avoid:
            g.add_edge(b.src, b.dst, bond=b.id)
    ground = ("ground",)
    for el in bg.elements:
        if el.type == "Sf" and el.id not in avoid:
            g.add_edge(el.id, ground, bond=None)
    if at not in g or not any(el.type == "I" for el in bg.elements):
        return []
    if ground in g and nx.has_path(g, at, ground):
        paths = sorted(nx.node_disjoint_paths(g, at, ground), key=len)
        if len(paths) >= 2:
            p1, p2 = paths[0], paths[1]
            return [x if x != ground else "ground" for x in p1[:-1] + [ground] + p2[::-1][1:-1]]
    return []


def closed_loop_error(bg: BondGraph, loop: list[str], why: str):
    """A closed kinematic loop: (where: the bond suggested for the compliant coupling, else
    None; the message: the loop and why; the advice: how to close it)."""
    names = [x for x in loop if x != "ground"]
    # the connections between bodies on the loop: bonds whose ends lie in different instances
    joints = []
    for a, b in zip(loop, loop[1:] + loop[:1]):
        for bd in bg.bonds:
            if {bd.src, bd.dst} == {a, b} and bd.src.rsplit(".", 1)[0] != bd.dst.rsplit(".", 1)[0]:
                joints.append(bd)
    # prefer the connection at the flow source that closes the loop (the last one written)
    grounded = [bd for bd in joints if bg.element(bd.src).type == "Sf"
                or bg.element(bd.dst).type == "Sf"]
    pick = max(grounded or joints, key=lambda bd: bd.index) if joints else None
    where = (f"bond {pick.id!r} ({pick.src} -> {pick.dst}, n={pick.n})" if pick
             else "one of its bonds")
    listed = ", ".join(names[:24]) + (f", ... ({len(names)} elements)" if len(names) > 24 else "")
    through = " (closed through the ground, its flow sources)" if "ground" in loop else ""
    message = f"closed kinematic loop{through} through {listed}: {why}"
    advice = ("Differentiating the constraint cannot hold it at position level.\n"
              f"Close the loop with one compliant coupling, e.g. at {where}:\n"
              "a 0-junction with a 1-junction carrying a C (stiffness k, say 1e6..1e8 for metal "
              "joints) in parallel with an R, in place of the rigid connection\n"
              "(the `joint` component of bench/planar_chain.py; the paper's remedy).")
    return (pick.coord if pick else None), message, advice


def closed_loop_message(bg: BondGraph, loop: list[str], why: str) -> str:
    """The closed loop's message and advice as one text (for reports that are not errors)."""
    _, message, advice = closed_loop_error(bg, loop, why)
    return message + ". " + " ".join(advice.splitlines())


def dependent_report(bg: BondGraph, caus: Causality, eqs=None) -> str:
    """What `bgc check` says about the storage elements in derivative causality."""
    lines = ["dependent storage elements (derivative causality, eliminated):"]
    deps = dict(eqs.dependent) if eqs is not None and getattr(eqs, "dependent", None) else {}
    for eid in caus.derivative:
        el = bg.element(eid)
        origin, via = caus.forced_by[eid]
        o = bg.element(origin)
        v = bg.element(via)
        through = (f"{v.type}-junction {via!r}" if v.type in ("0", "1") else f"{v.type} {via!r}")
        if el.type == "I":
            how = "p = M f, its flow f imposed by the causal path; its effort is dp/dt"
        else:
            how = "q = K^-1 e, its effort e imposed by the causal path; its flow is dq/dt"
        on = deps.get(eid)
        on_txt = f"; follows from {', '.join(on)}" if on else ""
        unused = "; its `initial:` is not used" if el.initial is not None else ""
        lines.append(f"  {el.type} {eid} (line {el.coord.line}): forced by {o.type} {origin} "
                     f"through {through}{on_txt}; {how}{unused}")
    return "\n".join(lines) + "\n"


def fixed_r_culprit(bg: BondGraph, caus: Causality):
    """(coord, message) when the storage elements in derivative causality were forced there by
    an R whose law fixes its form (``effort:`` of f sets the effort, ``flow:`` of e the flow):
    the R's law is in the form the graph cannot take, and the message says so, naming the R."""
    for eid in caus.derivative:
        origin, via = caus.forced_by[eid]
        o = bg.element(origin)
        if o.type != "R" or not o.law or o.law[0] not in FIXED_R:
            continue
        el = bg.element(eid)
        has = "resistance" if o.law[0] == "effort" else "conductance"
        needs = "conductance" if has == "resistance" else "resistance"
        other = "flow: an expression of e" if needs == "conductance" else \
            "effort: an expression of f"
        return o.coord, (f"R {origin!r}: its law ({o.law[0]}: ...) is in {has} form, but its "
                         f"causality must be {needs}: in {has} form it forces {el.type} {eid!r} "
                         f"into derivative causality (through {bg.element(via).id!r}). Write "
                         f"its law in {needs} form ({other}), or as resistance: r")
    return None


def derivative_message(bg: BondGraph, caus: Causality) -> str:
    parts = []
    for eid in caus.derivative:
        origin, via = caus.forced_by[eid]
        el = bg.element(eid)
        o = bg.element(origin)
        parts.append(f"{el.type} {eid!r} is forced into derivative causality by {o.type} "
                     f"{origin!r} through {bg.element(via).type}-junction {via!r}"
                     if bg.element(via).type in ("0", "1") else
                     f"{el.type} {eid!r} is forced into derivative causality by {o.type} "
                     f"{origin!r} through {via!r}")
    return ("derivative causality: " + "; ".join(parts) + ". Join the storage elements through "
            "a compliant coupling (a stiff C in parallel with an R, as Maini & Vaz do at every "
            "joint), or merge them into one element")
