"""Run reports: the numbers a person reads after a flight, from the companion's records and the truth."""

from __future__ import annotations

import numpy as np

from companion.loop.app import Companion
from companion.loop.records import describe_tracking

#: What makes an event an alert: the companion braked (stale estimate, no valid plan, a plan
#: too old), used safety slack, or lost control of the vehicle (pilot, link, gave up).
_ALERT_WORDS = ("braking", "stale", "PILOT_TOOK_OVER", "LINK_LOST", "GAVE_UP", "slack used", "position uncertain")


def companion_report(companion: Companion) -> dict:
    """What the companion itself saw and did (no ground truth needed).

    Contours of touch are confidences in [0, 1]; ``min_realised_contour`` is computed from
    the estimates at every replan request (in real time also those whose plan was superseded
    or never came back), ``min_planned_contour`` from the applied plans (obstacles in
    sensing range only). Solve times in milliseconds.
    """
    tally = companion.tally   # every applied replan, however few records a live flight keeps
    solve = np.array(tally.solve_times_s, dtype=float)   # a copy: a view would pin the array's size
    state = companion.state
    report = {
        "formulation": companion.planner_config.formulation,
        "c_min": companion.planner_config.c_min,
        "c_max": companion.planner_config.c_max,
        "engaged": companion.sequencer.state.engaged,
        "phase": companion.sequencer.phase.name,
        "goal_reached_companion_t_s": state.goal_reached_t_s,
        "min_estimated_clearance_m": state.min_track_clearance_m,
        "vehicle_mode": getattr(companion.sequencer, "vehicle_mode", None),
        "replans": tally.count,
        "plan_status": tally.status_counts(),
        "replans_with_slack": state.slack_plans,
        "failed_plans": state.failed_plans,
        "min_realised_contour": state.min_realised_contour,  # every request's, not only the applied plans'
        "min_planned_contour": tally.min_planned_contour,
        "solve_time_median_ms": float(np.median(solve) * 1e3) if solve.size else None,
        "solve_time_p99_ms": float(np.percentile(solve, 99) * 1e3) if solve.size else None,
        "stale_events": state.stale_events,
        "old_plan_events": state.old_plan_events,
        "estimator_resets": state.estimator_resets,
        "plans_before_reset": state.plans_before_reset,
        "position_uncertain_events": state.position_uncertain_events,
        "reported_position_sd_max_m": None if state.reported_position_sd_max_m is None
        else round(state.reported_position_sd_max_m, 3),
        "tracks_unconstrained_max": state.tracks_unconstrained_max,
        "tracks_beyond_walls_max": state.tracks_beyond_walls_max,
        "messages_rejected": state.messages_rejected,
        "obstacle_reports_rejected": state.obstacle_rejections + companion.obstacles.summary()["rejected_total"],
        "tracks": len(companion.tracker),
        "obstacle_intake": companion.obstacles.summary(),
        "vehicle_clock": companion.perception.clock.summary(),
        "tracking_error": state.tracking.summary(),
        "drift_max_mps": [round(v, 4) for v in state.drift_max_mps],
        # the events an operator must look at (braking, slack, lost control); not the autopilot's failsafes
        "alerts": [(round(t, 2), text) for t, text in state.events if any(w in text for w in _ALERT_WORDS)],
        "events": [(round(t, 2), text) for t, text in state.events],
    }
    if state.events.dropped:   # a long flight: the first and the latest are listed
        report["events_not_kept"] = state.events.dropped
    mission = getattr(companion.goal, "summary", None)   # a mission goal: the items reached
    if callable(mission):
        report.update(mission())
    if getattr(companion, "watch", None) is not None:   # watching (or guarding) the autopilot's own mission
        report["takeover"] = "guard" if getattr(companion, "guard", None) is not None else "watch"
        report.update(companion.watch.summary())
    if getattr(companion, "guard", None) is not None:
        report.update(companion.guard.summary())
    if getattr(companion, "goal_error", None):
        report["goal_error"] = companion.goal_error
    if getattr(companion, "fence", None) is not None:   # a geofence was flown: how far inside it the estimate kept
        report["min_fence_clearance_m"] = state.min_fence_clearance_m
    if getattr(companion, "peers", None) is not None:   # in a fleet: intents heard and used, rules of the road
        row = companion.builder.right_of_way
        report["fleet"] = {"coordination": companion.scenario.fleet.coordination, **companion.peers.summary(),
                           "min_peer_realised_contour": min_peer_contour(companion),
                           "sent": dict(companion.announcer.sent), **(row.summary() if row is not None else {})}
    return report


def min_peer_contour(companion: Companion) -> float | None:
    """The smallest realised contour of touch between the drone's estimate and a peer's (a track
    on the fleet link, keyed by its MAVLink system) over the run's replans; None: no peer heard."""
    return companion.tally.min_peer_contour


def truth_report(truth: dict) -> dict:
    """The simulator's ground truth in report form: collisions, distances (m), goal, final mode."""
    dist = truth.get("min_distance_m", {}) or {}
    clear = truth.get("min_clearance_m", {}) or {}
    walls = truth.get("min_wall_clearance_m") or []
    return {
        "scenario": truth.get("scenario"),
        "collided": bool(truth.get("collided")),
        "collisions": len(truth.get("collisions", [])),
        "goal_reached": bool(truth.get("goal_reached")),
        "time_to_goal_s": truth.get("time_to_goal_s"),
        "min_true_goal_distance_m": truth.get("min_goal_distance_m"),
        "min_true_distance_m": min(dist.values()) if dist else None,
        "min_true_clearance_m": min(clear.values()) if clear else None,
        "min_wall_clearance_m": min(walls) if walls else None,
        "final_mode": truth.get("final_mode"),
        "sim_time_s": truth.get("sim_time_s"),
    }


def run_report(companion: Companion, truth: dict | None) -> dict:
    """Companion report plus the simulator's ground truth (collisions, distances, goal), if any."""
    return {**(truth_report(truth) if truth else {}), **companion_report(companion)}


def _fmt(value: object) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def format_report(report: dict) -> str:
    """A short human-readable summary (one 'key: value' line each; events listed last)."""
    order = [
        ("outcome", "outcome"),
        ("stop_requested_by", "stop requested by"),
        ("goal_reached_companion_t_s", "goal reached at [s] (companion's estimate)"),
        ("min_estimated_clearance_m", "smallest clearance to a track, estimated [m]"),
        ("min_fence_clearance_m", "smallest distance inside the fence, est. [m]"),
        ("vehicle_mode", "autopilot's last mode"),
        ("scenario", "scenario"),
        ("formulation", "formulation"),
        ("c_min", "c_min"),
        ("c_max", "c_max"),
        ("collided", "collision"),
        ("goal_reached", "goal reached"),
        ("time_to_goal_s", "time to goal [s]"),
        ("min_true_distance_m", "smallest true distance [m]"),
        ("min_true_clearance_m", "smallest true clearance (distance - radii) [m]"),
        ("min_wall_clearance_m", "smallest wall clearance [m]"),
        ("min_realised_contour", "smallest realised contour of touch (estimates)"),
        ("min_planned_contour", "smallest planned contour of touch"),
        ("replans", "replans"),
        ("solve_time_median_ms", "planner solve time median [ms]"),
        ("solve_time_p99_ms", "planner solve time p99 [ms]"),
        ("replans_with_slack", "replans that used safety slack"),
        ("failed_plans", "failed plans"),
        ("stale_events", "stale-estimate events"),
        ("old_plan_events", "plan-too-old brakes"),
        ("tracks_unconstrained_max", "most tracks left unconstrained in a replan"),
        ("setpoint_rate_hz", "setpoint rate [Hz]"),
        ("setpoint_gap_max_ms", "largest setpoint gap [ms]"),
        ("final_mode", "final mode"),
    ]
    width = max(len(label) for _, label in order)
    lines = [f"{label.ljust(width)}  {_fmt(report.get(key))}" for key, label in order if key in report]
    gap = report.get("setpoint_gap_max_detail")
    if gap:
        lines.append(f"{'  where its time went'.ljust(width)}  {_gap_line(gap)}")
    tracking = report.get("tracking_error")
    if tracking:
        lines.append(f"{'strayed from the plan in force'.ljust(width)}  {describe_tracking(tracking)}")
    clock = report.get("vehicle_clock")
    if clock:
        lines.append(f"{'autopilot clock from'.ljust(width)}  {_clock_line(clock)}")
    intake = report.get("obstacle_intake")
    if intake:  # every rejected obstacle report, per source and reason (a silent drop is a defect)
        lines.append(f"{'obstacle reports accepted'.ljust(width)}  {sum(intake['accepted'].values())} from {len(intake['accepted'])} sources")
        lines.append(f"{'obstacle reports rejected'.ljust(width)}  {intake['rejected_total']}")
        lines.extend(f"  {n:6d}  {why}" for why, n in intake["rejected"].items())
        if intake.get("waiting_total"):  # before the vehicle clock or the origin was known: early, not wrong
            lines.append(f"{'obstacle reports before the time base'.ljust(width)}  {intake['waiting_total']}")
        lines.extend(f"  warning: {w}" for w in intake["warnings"])
    if "takeover" in report:   # the autopilot flew its own mission: what was predicted, taken over, reached
        lines.append(f"{'takeover'.ljust(width)}  {report['takeover']}")
        lines.append(f"{'conflicts predicted on the mission path'.ljust(width)}  {report.get('watch_conflicts_count')}")
        for k in report.get("takeovers", []):
            lines.append(f"  taken over at {_fmt(k['start_s'])} s ({k['reason']}; OFFBOARD shown {_fmt(k['decision_to_offboard_s'])} s "
                         f"later), given back at {_fmt(k['end_s'])} s")
        reached = report.get("mission_items_reached_by")
        if reached is not None:
            lines.append(f"{'mission items reached'.ljust(width)}  "
                         + (", ".join(f"{r['item']} ({r['by']})" for r in reached) or "none"))
    fs = report.get("alerts") or []
    lines.append(f"{'alerts (braking, slack, lost control)'.ljust(width)}  {len(fs)}")
    for t, text in fs:
        lines.append(f"  t={t:7.2f} s  {text}")
    return "\n".join(lines)


def _gap_line(gap: dict) -> str:
    """The largest setpoint gap's CPU time, run-queue wait, steal and longest loop step, in words."""
    wait = gap.get("run_queue_wait_ms")
    parts = [f"{gap['cpu_ms']} ms on a CPU", "run-queue wait unknown" if wait is None else f"{wait} ms waiting for one"]
    if gap.get("steal_ms") is not None:
        parts.append(f"{gap['steal_ms']} ms taken by the host (all CPUs)")
    if gap.get("longest_step"):
        parts.append(f"longest step {gap['longest_step']} {gap['longest_step_ms']} ms")
    mono = gap.get("monotonic_gap_ms")
    if mono is not None and abs(mono - gap["gap_ms"]) > 10.0:
        parts.append(f"the monotonic clock saw {mono} ms (the wall clock was set)")
    return ", ".join(parts)


def _clock_line(clock: dict) -> str:
    """How link time was mapped onto the autopilot's clock, in one line."""
    gap = clock["one_way_minus_timesync_ms"]  # arrival bound minus the TIMESYNC estimate
    if clock["source"] == "timesync":
        return (f"TIMESYNC (arrival bound {_fmt(gap)} ms above it; shortest round trip "
                f"{_fmt(clock['rtt_min_ms'])} ms, drift {_fmt(clock['drift'])})")
    if clock["timesync_disagrees"]:
        return "pose arrivals (TIMESYNC answers disagreed with the pose stamps)"
    if gap is None:
        return f"pose arrivals ({clock['timesync_answers']} TIMESYNC answers of {clock['timesync_requests']} requests)"
    if -gap < 0.05:
        return "pose arrivals (TIMESYNC agrees)"
    return f"pose arrivals (TIMESYNC answers stamped {_fmt(-gap)} ms late)"
