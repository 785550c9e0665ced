"""The measurement adapter's loop: a real sensor's readings in, the loop's observations out
(rules: docs/ros.md, "The loop's rules"; node: ``nodes/measurement_adapter.py``).

A sensor knows nothing of the loop's epochs, of the action in force or of the model's observation
bins; the adapter adds them, so that the filter gets exactly what a simulated target would send:
``[epoch, priority, z]`` (:class:`~.samples.ObservationSample`), or soft evidence ``[epoch,
priority, l(0..S-1)]`` (:class:`~.samples.LikelihoodSample`) from a sensor that gives a likelihood
per state. The rules, in the order a reading meets them (each bad reading is counted once, under
the first rule it fails, and dropped):

=====================  ====================================================================
rule                   what it says
=====================  ====================================================================
Value                  A scalar (``float64``, a ``range``, a ``point`` coordinate or norm) that
                       is NaN is dropped (``nan_readings``). A likelihood with a NaN is
                       ``nan_readings``; one that is not ``S`` finite non-negative values with
                       a positive one (the core's ``check_likelihood``) ``malformed_messages``.
Limits (range)         A finite range outside the message's ``[min_range, max_range]`` is
                       dropped (``out_of_limits_readings``), as sensor_msgs/Range says (limits
                       with ``max_range <= min_range``, e.g. left unset, are ignored); ``-inf``
                       (an object closer than ``min_range``) and ``+inf`` (nothing within
                       ``max_range``) are readings (REP 117) and go to the first and last bin.
Staleness              A stamped reading (a header stamp other than 0) more than ``max_age``
                       seconds older than the node's clock is dropped (``stale_readings``); one
                       stamped more than ``max_age`` in the future (a clock out of step) too
                       (``future_readings``). ``max_age`` 0: the stamps are not compared with
                       the node's clock at all (a sensor clock out of step): no such check, and
                       the numbering rule below takes arrival times. An unstamped reading
                       (``Float64``, a likelihood array, a zero stamp) is taken as of its arrival.
Ordering               A stamped reading not newer than the newest stamp seen is dropped
                       (``out_of_order_readings``). Unstamped readings are in arrival order.
Binning                A scalar ``x`` goes to observation ``z = #{k : e_k <= x}`` for the
                       ``bin_edges`` ``e_1 < ... < e_{Z-1}``: bin ``z`` is ``[e_z, e_{z+1})``,
                       with ``e_0 = -inf`` and ``e_Z = +inf`` (:class:`ObservationBins`).
Numbering              The adapter answers the newest action it heard, ``[t, p]``, with the
                       first valid reading taken at least ``settle_time`` after it heard the
                       action (by its stamp, if stamped), published once as ``[t, p, z]``
                       (``forwarded``). Readings taken earlier (``early_readings``) and readings
                       while the newest action is already answered (``surplus_readings``) are
                       dropped: one reading per decision, so the loop runs at the pace of the
                       slower of sensor and planner. An action superseded before a reading
                       answered it is counted (``unanswered_actions``; the filter's time-out
                       makes its epoch a gap).
Before the first       No reading is forwarded before the first action is heard: each is
action                 counted (``before_first_action``) and dropped. The planner's first action
                       (epoch 1, planned from the filter's prior) is answered by the first reading
                       after it.
Join, window, re-sync  As the simulator's (the rule "Join"): a (re)started adapter answers the
                       newest action received within :data:`~.epochs.JOIN_DELAY` of the first
                       (the planner's history arrives as one burst); actions beyond the epoch
                       window are dropped (``out_of_window``), repeated or older ones are
                       ``stale_actions``, and a persistent other numbering is re-synced to.
Re-send                The last observation is re-published every ``resend_period`` while no new
                       action answers it (``resent_observations``; the filter drops repeats).
=====================  ====================================================================

Every rule is a function of the values, stamps and the time the caller passes in (``now``:
seconds on the clock the stamps are on, the node's ROS clock); nothing here reads a clock, and
the loop keeps a fixed amount of state whatever the sensor's rate.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from ..belief import check_likelihood
from ..checks import check_choice, check_number
from ..errors import BeliefError, OptionError
from ..model import POMDP
from .epochs import EpochLine, JoinWait, Liveness, Resender
from .health import InputWatch, Log, LoopHealth, PeriodWatch, Report
from .samples import ActionSample, LikelihoodSample, ObservationSample

#: The adapter's inputs (parameter ``input_type``): ``std_msgs/Float64``, ``sensor_msgs/Range``,
#: ``geometry_msgs/PointStamped`` (scalars, binned), ``std_msgs/Float64MultiArray`` (a likelihood).
INPUT_TYPES = ("float64", "range", "point", "likelihood")
#: Rule "Pace": actions this many times slower than the readings (medians) are one warning.
PACE_FACTOR = 1.5
#: What a ``point`` input gives (parameter ``point_field``): a coordinate or the Euclidean norm.
POINT_FIELDS = ("x", "y", "z", "norm")

COUNTERS = ("readings", "forwarded", "nan_readings", "stale_readings", "future_readings", "out_of_order_readings",
            "out_of_limits_readings", "malformed_messages", "before_first_action", "early_readings",
            "surplus_readings", "unanswered_actions", "stale_actions", "malformed_actions", "out_of_window", "resyncs",
            "resent_observations")
#: Counts that make the report WARN when they grew since the previous one.
PROBLEMS = ("nan_readings", "stale_readings", "future_readings", "out_of_order_readings", "out_of_limits_readings",
            "malformed_messages", "malformed_actions", "out_of_window", "resyncs")


class ObservationBins:
    """A scalar reading to an observation index: ``bin_edges`` ``e_1 < ... < e_{Z-1}`` (``Z - 1``
    finite, strictly increasing edges for ``num_observations = Z``); :meth:`index` is
    ``#{k : e_k <= x}`` (module docstring, "Binning"). Bad edges raise :class:`OptionError`
    naming ``field``."""

    def __init__(self, edges: Sequence[float], num_observations: int, field: str = "bin_edges"):
        edges = list(edges)
        Z = num_observations
        if len(edges) != Z - 1:
            raise OptionError(f"{field}: {len(edges)} edges for an observation model with Z = {Z} observations "
                              f"(give Z - 1 = {Z - 1} increasing edges)")
        self.edges = [check_number(e, f"{field}[{k}]") for k, e in enumerate(edges)]
        for k in range(1, len(self.edges)):
            if not self.edges[k] > self.edges[k - 1]:
                raise OptionError(f"{field}: edges must increase strictly, but {field}[{k}] = {self.edges[k]:g} "
                                  f"<= {field}[{k - 1}] = {self.edges[k - 1]:g}")
        self.num_observations = Z

    def index(self, x: float) -> int:
        """The observation of scalar ``x`` (not NaN; ``-inf`` and ``+inf`` go to the end bins)."""
        return bisect.bisect_right(self.edges, x)


def point_value(x: float, y: float, z: float, point_field: str) -> float:
    """The scalar a ``point`` input gives: a coordinate or the Euclidean norm (NaN if any
    coordinate the value depends on is NaN)."""
    if point_field == "norm":
        return math.nan if math.isnan(x) or math.isnan(y) or math.isnan(z) else math.hypot(x, y, z)
    return {"x": x, "y": y, "z": z}[point_field]


@dataclass
class AdapterOutput:
    """What one call of the loop asks the node to do: publish ``samples`` in order (observations,
    or soft evidence for a likelihood input), log ``logs``, and call :meth:`AdapterLoop.join_due`
    at ``join_at`` (``None``: no join pending)."""

    samples: list[ObservationSample | LikelihoodSample] = field(default_factory=list)
    logs: list[Log] = field(default_factory=list)
    join_at: float | None = None


@dataclass(frozen=True)
class _Pending:
    """The newest action heard: its epoch and priority, when it was heard, and whether answered."""

    epoch: int
    priority: int
    heard_at: float
    answered: bool = False


class AdapterLoop:
    """The adapter of one sensor for ``model`` (module docstring).

    ``input_type``: one of :data:`INPUT_TYPES`. A scalar input needs ``bin_edges`` for the
    ``num_observations`` (``Z``) of the observation model the filter applies to its topic (no
    edges for ``Z = 1``); a likelihood input takes ``S`` values and no edges. ``point_field``:
    one of :data:`POINT_FIELDS` (used by ``point``). ``max_age`` and ``settle_time``: seconds
    (module docstring). ``input_name``: the sensor's topic, as diagnostics name it. Bad values
    raise :class:`OptionError` naming the parameter.
    """

    def __init__(self, model: POMDP, live: Liveness, *, now: float, input_type: str = "float64",
                 bin_edges: Sequence[float] | None = None, num_observations: int | None = None,
                 point_field: str = "norm", max_age: float = 1.0, settle_time: float = 0.0,
                 input_name: str = "measurement"):
        self.model = model
        self.live = live
        self.input_type = check_choice(input_type, INPUT_TYPES, "input_type")
        self.point_field = check_choice(point_field, POINT_FIELDS, "point_field")
        self.soft = self.input_type == "likelihood"
        edges = list(bin_edges or [])
        if self.soft:
            if edges:
                raise OptionError(f"bin_edges: not used with input_type likelihood (it gives one value per state), "
                                  f"got {len(edges)} edges")
            self.bins = None
        else:
            Z = model.Z if num_observations is None else num_observations
            if bin_edges is None and Z > 1:
                raise OptionError(f"bin_edges: needed for input_type {self.input_type}: Z - 1 = {Z - 1} increasing "
                                  "edges, one between each two observations")
            self.bins = ObservationBins(edges, Z)
        self.max_age = check_number(max_age, "max_age", 0.0)
        self.settle_time = check_number(settle_time, "settle_time", 0.0)
        self.input_name = input_name
        self.joined = False
        self.joined_at = "not yet"
        self._join = JoinWait()
        self._held: ActionSample | None = None
        self.pending: _Pending | None = None
        self.newest_stamp: float | None = None
        self.last_value: float | None = None
        self.line = EpochLine(live.epoch_window, now=now)
        self.action_watch = InputWatch("action", "action", started=now)
        self.sensor_watch = InputWatch(input_name, "reading", started=now)
        # rule "Pace": a sensor's bursts must not shorten its period, a planner's pause not lengthen the actions'
        self.reading_pace, self.action_pace = PeriodWatch("mean"), PeriodWatch("median")
        self._pace_warned = False
        self.health = LoopHealth(COUNTERS, PROBLEMS, [self.sensor_watch, self.action_watch], live.stall)
        self.resender = Resender(live.resend_period)
        self._last: ObservationSample | LikelihoodSample | None = None
        self._waiting_logged = False
        self._out = AdapterOutput()

    # ----------------------------------------------------------- inputs
    def start(self, now: float) -> AdapterOutput:
        if self.soft:
            what = f"likelihood over {self.model.S} states, forwarded as soft evidence"
        else:
            what = (f"{self.input_type}" + (f" ({self.point_field})" if self.input_type == "point" else "")
                    + f" binned into {self.bins.num_observations} observations at {self.bins.edges}")
        self.health.log("info", f"{self.model.describe()}; {self.input_name}: {what}; max_age {self.max_age:g} s, "
                        f"settle_time {self.settle_time:g} s; waiting for the first action")
        return self._result(now)

    def measurement(self, value: float | Sequence[float], now: float, *, stamp: float | None = None,
                    limits: tuple[float, float] | None = None) -> AdapterOutput:
        """One reading of the sensor: ``value`` a scalar, or ``S`` values for a likelihood input;
        ``stamp``: its header stamp (seconds; ``None`` or 0: unstamped); ``limits``: a range's
        ``(min_range, max_range)`` (ignored unless ``max_range > min_range``). Forwarded as the
        answer to the newest action, or counted and dropped (module docstring)."""
        self.health.count("readings")
        reading = self._valid_value(value, limits, now)
        if reading is None or not self._valid_stamp(stamp, now):
            self.sensor_watch.arrived(now, False)
            return self._result(now)
        self.reading_pace.arrived(now)
        taken = stamp if stamp and self.max_age > 0 else now  # max_age 0: stamps not on this clock
        self._try_join(now)
        pending, answered = self.pending, None
        if pending is None:
            self.health.count("before_first_action")
            if not self._waiting_logged:
                self._waiting_logged = True
                self.health.log("info", f"{self.input_name}: readings are dropped until the first action is heard "
                                "(counted as before_first_action)")
        elif pending.answered:
            self.health.count("surplus_readings")
            self._check_pace()
        elif taken < pending.heard_at + self.settle_time:
            self.health.count("early_readings")
        else:
            self._forward(pending, reading, now)
            answered = pending.epoch
        self.sensor_watch.arrived(now, True, answered)  # a valid reading is the sensor's progress
        return self._result(now)

    def _check_pace(self) -> None:
        """Rule "Pace": actions slower than the sensor's readings (the median period of the actions
        over :data:`PACE_FACTOR` times the readings' mean period) is one warning: the decisions (the
        planner's ``time_budget`` and its overhead) take longer than the sensor period."""
        readings, actions = self.reading_pace.period(), self.action_pace.period()
        if self._pace_warned or readings is None or actions is None or actions <= PACE_FACTOR * readings:
            return
        self._pace_warned = True
        self.health.log("warning", f"actions come every {actions:.3g} s, {self.input_name} readings every "
                        f"{readings:.3g} s (median, mean): a decision takes longer than the sensor period and the "
                        "readings in between are not used (surplus_readings); keep the planner's time_budget below "
                        "the sensor period")

    def rejected_measurement(self, problem: str, now: float) -> AdapterOutput:
        """A sensor message that could not be decoded (``problem``, e.g. a wrong layout)."""
        self.health.count("readings")
        self.health.reject(self.sensor_watch, "malformed_messages", f"{self.input_name}: ignored {problem}", now)
        return self._result(now)

    def action(self, act: ActionSample, now: float) -> AdapterOutput:
        """One decoded action: the newest one within the window is the one to answer next."""
        if not self.joined:
            if self._held is None or act.epoch > self._held.epoch:
                self._held = act
            self._join.note(act.epoch, now)
            return self.join_due(now)
        verdict = self.line.classify(act.epoch)
        if verdict in ("next", "ahead"):
            self.action_watch.arrived(now, True, act.epoch)
            self.action_pace.arrived(now)
            self._accept(act, now)
            return self._result(now)
        self.action_watch.arrived(now, False)
        if verdict == "out_of_window":
            self.health.warn("out_of_window", f"action of epoch {act.epoch} is beyond the epoch window "
                             f"({self.live.epoch_window}) of epoch {self.line.position}: dropped (a restarted "
                             "planner or a forged message)", now)
        else:
            self.health.count("stale_actions")
        if verdict != "repeat":
            self.line.off_line(act.epoch, act, now)
            self._resync_if_due(now)
        return self._result(now)

    def rejected_action(self, problem: str, now: float) -> AdapterOutput:
        self.health.reject(self.action_watch, "malformed_actions", f"ignored action: {problem}", now)
        return self._result(now)

    def join_due(self, now: float) -> AdapterOutput:
        """Join once the evidence of the loop's epoch has settled (module docstring)."""
        self._try_join(now)
        return self._result(now)

    def watchdog(self, now: float) -> AdapterOutput:
        """The join, re-send and re-sync rules on time alone."""
        self._try_join(now)
        if self.resender.due(now) and self._last is not None:
            self._out.samples.append(self._last)
            self.resender.resending(now)
            self.health.count("resent_observations")
        self._resync_if_due(now)
        return self._result(now)

    def report(self, now: float) -> Report:
        p = self.pending
        if p is None:
            head = "waiting for the first action" if self.joined or self._held is None else "joining"
        else:
            head = f"epoch {p.epoch} " + ("answered" if p.answered else "waiting for a reading")
        last = self._last
        values = {"epoch": "none" if p is None else p.epoch, "joined_at": self.joined_at,
                  "input_type": self.input_type, "last.value": "none" if self.last_value is None else self.last_value,
                  "last.observation": "none" if last is None else
                  ("likelihood" if self.soft else last.observation),
                  "param.max_age": self.max_age, "param.settle_time": self.settle_time}
        if self.bins is not None:
            values["param.bin_edges"] = ", ".join(f"{e:g}" for e in self.bins.edges)
        return self.health.report(now, values, head=[head])

    # ----------------------------------------------------------- rules
    def _valid_value(self, value, limits, now: float) -> int | tuple[float, ...] | None:
        """The reading to forward (an observation index or a likelihood), or ``None`` (counted)."""
        name = self.input_name
        if self.soft:
            values = tuple(float(v) for v in value)
            if any(math.isnan(v) for v in values):
                self.health.warn("nan_readings", f"{name}: likelihood with NaN dropped", now)
                return None
            try:
                check_likelihood(self.model, values, field=f"{name}: likelihood")
            except BeliefError as exc:
                self.health.warn("malformed_messages", f"{exc}; dropped", now)
                return None
            return values
        x = float(value)
        if math.isnan(x):
            self.health.warn("nan_readings", f"{name}: NaN reading dropped", now)
            return None
        if limits is not None and limits[1] > limits[0] and math.isfinite(x) and not limits[0] <= x <= limits[1]:
            self.health.warn("out_of_limits_readings", f"{name}: range {x:g} outside the message's [min_range, "
                             f"max_range] = [{limits[0]:g}, {limits[1]:g}]; dropped", now)
            return None
        self.last_value = x
        return self.bins.index(x)

    def _valid_stamp(self, stamp: float | None, now: float) -> bool:
        """Staleness and ordering of a stamped reading (module docstring); counted when it fails."""
        if not stamp:
            return True
        name = self.input_name
        age = now - stamp
        if self.max_age > 0 and age > self.max_age:
            self.health.warn("stale_readings", f"{name}: reading stamped {age:.3g} s ago (max_age "
                             f"{self.max_age:g} s); dropped", now)
            return False
        if self.max_age > 0 and -age > self.max_age:
            self.health.warn("future_readings", f"{name}: reading stamped {-age:.3g} s in the future (max_age "
                             f"{self.max_age:g} s: is the sensor's clock in step?); dropped", now)
            return False
        if self.newest_stamp is not None and stamp <= self.newest_stamp:
            self.health.warn("out_of_order_readings", f"{name}: reading stamped {self.newest_stamp - stamp:.3g} s "
                             "before the newest one seen; dropped", now)
            return False
        self.newest_stamp = stamp
        return True

    def _forward(self, pending: _Pending, reading, now: float) -> None:
        if self.soft:
            sample = LikelihoodSample(pending.epoch, pending.priority, reading)
        else:
            sample = ObservationSample(pending.epoch, pending.priority, reading)
        self.pending = _Pending(pending.epoch, pending.priority, pending.heard_at, answered=True)
        self._last = sample
        self._out.samples.append(sample)
        self.health.count("forwarded")
        self.resender.published(now)

    def _accept(self, act: ActionSample, now: float) -> None:
        """``act`` is the action to answer next (its epoch the adapter's position)."""
        if self.pending is not None and not self.pending.answered:
            self.health.count("unanswered_actions")
            self.health.log("debug", f"action of epoch {self.pending.epoch} superseded by epoch {act.epoch} "
                            "before a reading answered it")
        self.pending = _Pending(act.epoch, act.priority, now)
        self.line.advance(act.epoch, now)
        self.resender.answered()

    def _try_join(self, now: float) -> None:
        if self.joined or self._held is None or not self._join.settled(now):
            return
        held, self._held = self._held, None
        self.joined = True
        self.joined_at = f"epoch {held.epoch}"
        self.health.log("info", f"joined the loop at epoch {held.epoch} (the newest action received); answering it "
                        "with the next reading")
        self.action_watch.arrived(now, True, held.epoch)
        self._accept(held, now)

    def _resync_if_due(self, now: float) -> None:
        due = self.line.resync_due(self.live.stall.warn_after, now)
        if due is None:
            return
        self.health.warn("resyncs", self.line.resync_reason(due, "actions", "planner", now), now)
        self.line.resync(due.epoch, now)
        self.pending = None  # _accept must not count the old one as unanswered: it is another numbering
        self._accept(due.payload, now)

    def _result(self, now: float) -> AdapterOutput:
        out, self._out = self._out, AdapterOutput()
        out.logs = self.health.drain_logs()
        out.join_at = None if self.joined else self._join.wake_at(now)
        return out
