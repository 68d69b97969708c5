"""The bench's results as tables for people."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from supervisor.tools.bench.latency import TESSLA_MEAN_MS, THESIS_MEAN_MS
from supervisor.tools.bench.numbers import shown
from supervisor.tools.bench.plan import DEPTH


def _f(x: float | None, fmt: str = ".2f") -> str:
    return shown(x, fmt)


def format_results(r: dict[str, Any]) -> str:
    lines = [
        f"safety-supervisor bench: {r['config']} ({len(r['topics'])} topics, trigger {r['trigger']})",
        f"machine: {r['cpus']} CPUs, load average {r['loadavg_before']} before, "
        f"{r['loadavg_after']} after; Python {r['python']}; RMW {r['rmw']}; "
        f"ROS_DOMAIN_ID={r.get('domain_id')}, localhost discovery",
    ]
    if "throughput" in r:
        lines += ["", *_format_throughput(r["throughput"])]
    if "recording" in r:
        lines += ["", *_format_recording(r["recording"])]
    if "ui" in r:
        lines += ["", *_format_ui(r["ui"])]
    if "scan" in r:
        lines += ["", *_format_scan(r["scan"])]
    if "scale" in r:
        lines += ["", *_format_scale(r["scale"])]
    if "soak" in r:
        lines += ["", *_format_soak(r["soak"])]
    if "latency" in r:
        lines += ["", *_format_latency(r["latency"])]
    if "replay" in r:
        lines += ["", *_format_replay(r["replay"])]
    return "\n".join(lines)


def _mb(kb: int | None) -> str:
    return "-" if kb is None else f"{kb / 1024:.1f}"


def _check_text(c: dict[str, Any]) -> str:
    if c["timeout"]:
        return "check killed at its time limit"
    return f"{_f(c['wall_s'], '.1f')} s, exit {c['exit']}, peak RSS {_mb(c.get('maxrss_kb'))} MB"


def _scale_rows(sc: dict[str, Any]) -> list[list[str]]:
    """One row per size: the columns of both tables."""
    out = []
    for row in sc["rows"]:
        d, c = row["daemon"], row["check"]
        out.append(
            [
                str(row["requirements"]),
                f"{row['parse_formalize_s']:.2f}",
                "-" if c["wall_s"] is None else f"{c['wall_s']:.1f}",
                str(c["exit"]),
                f"{row['compile_s']:.2f}",
                str(row["library_bytes"]),
                f"{row['tick_ns']:.0f}",
                f"{row['tick_ns_per_requirement']:.1f}",
                _f(d["ready_s"], ".1f"),
                _f(d["cpu_us_per_msg"], ".1f"),
                str(d["lost"]),
                str(d["violations"]),
                _mb(d["rss_start_kb"]),
                _mb(d["rss_end_kb"]),
                _mb(d["hwm_end_kb"]),
            ]
        )
    return out


SCALE_HEAD = [
    "reqs",
    "parse+formalize s",
    "check s",
    "check exit",
    "compile s",
    "library bytes",
    "ns/tick",
    "ns/tick/req",
    "daemon ready s",
    "CPU us/msg",
    "lost",
    "violations",
    "RSS start MB",
    "RSS end MB",
    "HWM end MB",
]


def _format_scale(sc: dict[str, Any]) -> list[str]:
    ref = sc["reference"]
    lines = [
        f"Scaling: generated configs over 50 inputs (seed {sc['seed']}); the daemon at "
        f"{sc['offered']:g} msg/s over their 50 topics for {sc['seconds']:g} s (one tick per "
        "round of 50, every value zero)",
        "  " + " | ".join(SCALE_HEAD),
    ]
    lines += ["  " + " | ".join(cells) for cells in _scale_rows(sc)]
    for row in sc["rows"]:
        c = row["check"]
        lines.append(f"  check of {row['requirements']}: {_check_text(c)}; {c['last']}")
        lines += [f"    {ln.strip()}" for ln in c["analysis"]]
    lines.append(
        f"  the daemon on {ref['config']} ({ref['topics']} topics) at {ref['offered']:g} msg/s: "
        f"RSS {_mb(ref['rss_start_kb'])} MB once ready, {_mb(ref['rss_end_kb'])} MB at the end "
        f"(HWM {_mb(ref['hwm_end_kb'])} MB), CPU {_f(ref['cpu_us_per_msg'], '.1f')} us/msg, "
        f"lost {ref['lost']}"
    )
    return lines


def _format_soak(so: dict[str, Any]) -> list[str]:
    return [
        f"Soak: the daemon on {so['config']} at {so['offered']:g} msg/s for {so['seconds']:.0f} s, "
        f"{so['n_samples']} samples every {so['interval_s']:g} s",
        f"  RSS first {_mb(so['rss_first_kb'])} MB, last {_mb(so['rss_last_kb'])} MB, max "
        f"{_mb(so['rss_max_kb'])} MB (HWM {_mb(so['hwm_last_kb'])} MB); slope over the second "
        f"half {_f(so['rss_slope_kb_per_min_second_half'], '+.1f')} kB/min "
        f"({so['second_half_samples']} samples)",
        f"  open fds first {so['fds_first']}, last {so['fds_last']}, max {so['fds_max']} "
        f"(growth {so['fds_growth']})",
        f"  sent {so['sent']} ({so['achieved']:.0f} msg/s achieved), received {so['received']}, "
        f"lost {so['lost']} ({so['loss_pct']:.3f} %; counted lost {so['counted_lost']}), "
        f"violations {so['violations']}, CPU {_f(so['cpu_us_per_msg'], '.1f')} us/msg, longest "
        f"ping gap {_f(so['longest_ping_gap_ms'], '.0f')} ms",
    ]


def _format_recording(rows: list[dict[str, Any]]) -> list[str]:
    lines = [
        "Recording overhead: the daemon without and with run --record DIR, same offered rate",
        f"  {'offered':>8} {'record':>6} {'sent':>8} {'received':>8} {'lost':>6} "
        f"{'CPU us/msg':>10} {'to exit':>8} {'written':>8} {'dropped':>7} {'MB':>6}",
    ]
    for row in rows:
        for label in ("off", "on"):
            side = row[label]
            rec = side["record"] or {}
            lines.append(
                f"  {row['offered']:>8g} {label:>6} {side['sent']:>8} {side['received']:>8} "
                f"{side['lost']:>6} {_f(side['cpu_us_per_msg'], '.1f'):>10} "
                f"{_f(side['cpu_us_per_msg_to_exit'], '.1f'):>8} {rec.get('written', '-'):>8} "
                f"{rec.get('dropped', '-'):>7} {_f(rec.get('mb_on_disk'), '.1f'):>6}"
            )
        diff = row["cpu_diff_pct"]
        verdict = "" if diff is None else (" (within)" if diff <= row["goal_pct"] else " (above)")
        lines.append(
            f"  CPU per message with recording: {_f(diff, '+.1f')} % during the run, "
            f"{_f(row['cpu_diff_pct_to_exit'], '+.1f')} % up to exit; goal within "
            f"{row['goal_pct']:g} %{verdict}"
        )
    return lines


def _scan_rows(sc: dict[str, Any]) -> list[tuple[str, dict[str, Any]]]:
    return [("without the scan", sc["off"]), ("with the scan", sc["on"])]


def _reduction_rows(sc: dict[str, Any]) -> list[tuple[str, dict[str, Any]]]:
    red = sc["reduction"]
    return [
        ("reduce: min, message built by rclpy", red["reduce_built_us"]),
        ("reduce: min, deserialised message", red["reduce_deserialised_us"]),
        (f"deserialise_message ({red['cdr_bytes']} bytes)", red["deserialise_us"]),
        ("age_of reader (header.stamp)", red["age_reader_us"]),
    ]


def _format_scan(sc: dict[str, Any]) -> list[str]:
    red = sc["reduction"]
    lines = [
        f"LaserScan beside the stream: {sc['readings']} readings at {sc['hz']:g} Hz on "
        f"{sc['topic']}, obstacle = reduce: min over ranges, scan_age_ms = age_of obstacle, "
        f"one requirement on both; the stream at {sc['offered']:g} msg/s for {sc['seconds']:g} s",
        f"  {'daemon':<18} {'sent':>8} {'received':>8} {'lost':>6} {'loss %':>7} "
        f"{'scans sent/taken':>16} {'CPU us/msg':>10} {'to exit':>8} {'violations':>10}",
    ]
    for label, side in _scan_rows(sc):
        scans = f"{side['scans_sent']}/{side['scans_received']}"
        lines.append(
            f"  {label:<18} {side['sent']:>8} {side['received']:>8} {side['lost']:>6} "
            f"{side['loss_pct']:>7.2f} {scans:>16} {_f(side['cpu_us_per_msg'], '.1f'):>10} "
            f"{_f(side['cpu_us_per_msg_to_exit'], '.1f'):>8} {_f(side['violations'], 'g'):>10}"
        )
    lines.append(
        f"  CPU per message with the scan: {_f(sc['cpu_diff_pct'], '+.1f')} %, loss "
        f"{sc['loss_pct_diff']:+.2f} points; CPU added per scan taken "
        f"{_f(sc['cpu_us_per_scan_added'], '.0f')} us (one run each)"
    )
    lines.append(
        f"  in this process, {red['scans']} scans ({red['readings']} readings, "
        f"min {red['obstacle']:g}):"
    )
    for label, st in _reduction_rows(sc):
        lines.append(
            f"    {label:<40} p50 {st['p50']:>7.2f} us  p99 {st['p99']:>7.2f} us  "
            f"mean {st['mean']:>7.2f} us"
        )
    return lines


def _spread(sp: dict[str, float] | None, fmt: str) -> str:
    """min-max of per-client figures (``ui``'s spreads)."""
    if sp is None:
        return "-"
    lo, hi = format(sp["min"], fmt), format(sp["max"], fmt)
    return lo if lo == hi else f"{lo}-{hi}"


def _ui_case(row: dict[str, Any], clients: int) -> str:
    return row["case"].replace("clients", f"{clients} clients")


def _restart_text(ui: dict[str, Any]) -> str:
    """After the UI was killed: how long until the clients were back, and had status."""
    rs = ui.get("restart")
    if rs is None:
        return "  ui killed: the restart did not happen (the run ended first)"
    where = "while the publisher ran" if rs["within_run"] else "NOT while the publisher ran"
    return (
        f"  ui SIGKILLed {rs['killed_after_s']:.1f} s into the run, started again in "
        f"{rs['restart_took_s']:.2f} s: {rs['clients_reconnected']}/{ui['clients']} clients "
        f"connected again after {_spread(rs['connected_again_s'], '.2f')} s, "
        f"{rs['clients_with_status_again']} had the daemon's status again after "
        f"{_spread(rs['status_again_s'], '.2f')} s ({where})"
    )


def _chromium_text(row: dict[str, Any]) -> list[str]:
    """The one headless Chromium page (``--ui-chromium``), apart from the HTTP clients."""
    lines = []
    for c in row["cases"][1:]:
        page = (c["ui"] or {}).get("chromium")
        if page is None:
            continue
        what = f"  headless Chromium page ({c['case']}):"
        if page["error"] is not None:
            lines.append(f"{what} not opened: {page['error']}")
            continue
        text = (
            f"{what} {page['events']} events, {page['events_in_run']} while the publisher ran, "
            f"longest gap {page['longest_gap_s']:.2f} s, {page['connects']} streams opened"
        )
        if page["status_again_s"] is not None or page["connected_again_s"] is not None:
            text += (
                f"; connected again after {_f(page['connected_again_s'])} s, status again "
                f"after {_f(page['status_again_s'])} s"
            )
        lines.append(text)
    return lines


def _format_ui(rows: list[dict[str, Any]]) -> list[str]:
    lines = []
    for row in rows:
        n = row["clients"]
        lines += [
            f"UI load: the daemon at {row['offered']:g} msg/s for {row['seconds']:g} s without "
            f"a UI, with `ui` and {n} clients on /events, and with the UI killed halfway and "
            "restarted",
            f"  {'case':<26} {'sent':>8} {'received':>8} {'lost':>6} {'CPU us/msg':>10} "
            f"{'diff %':>7} {'events/client':>13} {'in run':>9} {'gap s':>6} {'ui ms/s':>7}",
        ]
        for c in row["cases"]:
            ui = c["ui"] or {}
            cpu = ui.get("ui_cpu_ms_per_s") or ui.get("ui_cpu_ms_per_s_until_kill")
            lines.append(
                f"  {_ui_case(c, n):<26} {c['sent']:>8} {c['received']:>8} {c['lost']:>6} "
                f"{_f(c['cpu_us_per_msg'], '.1f'):>10} {_f(c['cpu_diff_pct'], '+.1f'):>7} "
                f"{_spread(ui.get('events'), 'g'):>13} {_spread(ui.get('events_in_run'), 'g'):>9} "
                f"{_f(ui.get('longest_gap_s'), '.2f'):>6} {_f(cpu, '.1f'):>7}"
            )
        restarted = row["cases"][2]["ui"]
        lines += [
            _restart_text(restarted),
            *_chromium_text(row),
            "  (events/client: SSE events each client received in all and while the publisher "
            "ran; gap: the longest time a client had none then; ui ms/s: the UI's CPU per "
            "second while the publisher ran, until the kill in the last case)",
            f"  daemon CPU per message with the UI: {_f(row['cases'][1]['cpu_diff_pct'], '+.1f')}"
            f" %, killed and restarted {_f(row['cases'][2]['cpu_diff_pct'], '+.1f')} %; goal "
            f"within {row['goal_pct']:g} % and no more lost",
        ]
    return lines


def _format_replay(rep: dict[str, Any]) -> list[str]:
    lines = [
        f"Replay throughput: bags of {rep['messages']} messages (recorded at "
        f"{rep['recorded_rate']:g} msg/s), replayed in this process, replay's own clock",
        f"  {'case':<44} {'messages':>9} {'ticks':>8} {'violations':>10} {'seconds':>8} "
        f"{'msg/s':>10} {'bag MB':>7}",
    ]
    for c in rep["cases"]:
        lines.append(
            f"  {c['case']:<44} {c['messages']:>9} {c['ticks']:>8} {c['violations']:>10} "
            f"{c['seconds']:>8.3f} {c['rate']:>10.0f} {c['bag_mb']:>7.1f}"
        )
    for storage, r in rep.get("by_storage", {}).items():
        lines.append(f"  {_STORAGE[storage]}: {_rate_range(r)}")
    lines.append("  monitor alone (native, random inputs): " + _monitor_rates(rep["monitor"]))
    return lines


_STORAGE = {"mcap": "MCAP, bulk stepping", "sqlite3": "sqlite3, bulk stepping"}


def _rate_range(r: dict[str, float]) -> str:
    """A storage's msg/s over its bulk cases, as BENCHMARKS.md quotes it."""
    low, high = r["min"] / 1e6, r["max"] / 1e6
    span = f"{low:.2f} M msg/s" if low == high else f"{low:.2f}-{high:.2f} M msg/s"
    return f"{span} ({r['cases']:.0f} cases)"


def _monitor_rates(m: dict[str, float]) -> str:
    parts = [f"{k} {v / 1e6:.2f} M/s" for k, v in m.items()]
    return "ticks/s of " + ", ".join(parts) + " (pack: rows/s)"


def format_markdown(r: dict[str, Any]) -> str:
    """Every figure of the run as Markdown tables (``bench --out``)."""
    out = [
        "# safety-supervisor bench",
        "",
        "| | |",
        "| --- | --- |",
        f"| config | `{r['config']}` ({len(r['topics'])} topics, trigger `{r['trigger']}`) |",
        f"| CPUs | {r['cpus']} |",
        f"| load average | {r['loadavg_before']} before, {r['loadavg_after']} after |",
        f"| Python | {r['python']} |",
        f"| RMW | {r['rmw']} |",
        f"| ROS_DOMAIN_ID | {r.get('domain_id')} |",
    ]
    for key, section in _MD_SECTIONS:
        if key in r:
            out += section(r)
    return "\n".join(out) + "\n"


def _md_throughput(r: dict[str, Any]) -> list[str]:
    """The Markdown of ``bench --out``'s Throughput and overhead section."""
    out = [
        "",
        "## Throughput and overhead (eq. 1)",
        "",
        "| burst | offered msg/s | sent | achieved msg/s | receiver | received | loss % "
        "| msg/s | CPU s | CPU us/msg | overhead % | ping gap ms | lost: gaps / before "
        "first / after last |",
        "| ---: | ---: | ---: | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: "
        "| --- |",
    ]
    for row in r["throughput"]:
        loss = row["daemon_loss"]
        for name, rc in row["receivers"].items():
            daemon = name == "daemon"
            out.append(
                f"| {row.get('burst') or '-'} | {row['offered']:g} | {row['sent']} "
                f"| {row['achieved']:.0f} | {name} | {rc['received']} | {rc['loss_pct']:.2f} "
                f"| {rc['msg_per_s']:.0f} | {rc['cpu_s']:.2f} "
                f"| {_f(rc['cpu_us_per_msg'], '.1f')} "
                f"| {_f(row['overhead_pct']) if daemon else ''} "
                f"| {_f(row.get('longest_ping_gap_ms'), '.0f') if daemon else ''} "
                + (
                    f"| {loss['gaps']} / {loss['before_first']} / {loss['after_last']} |"
                    if daemon
                    else "| |"
                )
            )
    return out


def _md_recording(r: dict[str, Any]) -> list[str]:
    """The Markdown of ``bench --out``'s Recording overhead section."""
    out = [
        "",
        "## Recording overhead (run --record)",
        "",
        "| offered msg/s | record | sent | received | lost | CPU us/msg | CPU us/msg to exit "
        "| written | dropped | MB on disk | CPU difference % |",
        "| ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for row in r["recording"]:
        for label in ("off", "on"):
            side = row[label]
            rec = side["record"] or {}
            diff = (
                f"{_f(row['cpu_diff_pct'], '+.1f')} (to exit "
                f"{_f(row['cpu_diff_pct_to_exit'], '+.1f')}; goal {row['goal_pct']:g})"
                if label == "on"
                else ""
            )
            out.append(
                f"| {row['offered']:g} | {label} | {side['sent']} | {side['received']} "
                f"| {side['lost']} | {_f(side['cpu_us_per_msg'], '.1f')} "
                f"| {_f(side['cpu_us_per_msg_to_exit'], '.1f')} | {rec.get('written', '')} "
                f"| {rec.get('dropped', '')} | {_f(rec.get('mb_on_disk'), '.1f')} | {diff} |"
            )
    return out


def _md_ui(r: dict[str, Any]) -> list[str]:
    """The Markdown of ``bench --out``'s UI load section."""
    out: list[str] = []
    for row in r["ui"]:
        n = row["clients"]
        out += [
            "",
            f"## UI load (`ui` with {n} clients on /events, {row['offered']:g} msg/s, "
            f"{row['seconds']:g} s)",
            "",
            "| case | sent | received | lost | CPU us/msg | CPU difference % | events per "
            "client | while publishing | longest gap s | ui CPU ms/s |",
            "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
        ]
        for c in row["cases"]:
            ui = c["ui"] or {}
            cpu = ui.get("ui_cpu_ms_per_s") or ui.get("ui_cpu_ms_per_s_until_kill")
            out.append(
                f"| {_ui_case(c, n)} | {c['sent']} | {c['received']} | {c['lost']} "
                f"| {_f(c['cpu_us_per_msg'], '.1f')} | {_f(c['cpu_diff_pct'], '+.1f')} "
                f"| {_spread(ui.get('events'), 'g')} | {_spread(ui.get('events_in_run'), 'g')} "
                f"| {_f(ui.get('longest_gap_s'), '.2f')} | {_f(cpu, '.1f')} |"
            )
        out += ["", _restart_text(row["cases"][2]["ui"]).strip()]
        out += [f"\n{line.strip()}" for line in _chromium_text(row)]
    return out


def _md_scan(r: dict[str, Any]) -> list[str]:
    """The Markdown of ``bench --out``'s a LaserScan beside the stream section."""
    out: list[str] = []
    sc = r["scan"]
    out += [
        "",
        f"## LaserScan beside the stream ({sc['readings']} readings at {sc['hz']:g} Hz, "
        f"reduce: min and age_of; {sc['offered']:g} msg/s, {sc['seconds']:g} s)",
        "",
        "| daemon | sent | received | lost | loss % | scans sent | scans taken "
        "| CPU us/msg | CPU us/msg to exit | violations |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for label, side in _scan_rows(sc):
        out.append(
            f"| {label} | {side['sent']} | {side['received']} | {side['lost']} "
            f"| {side['loss_pct']:.2f} | {side['scans_sent']} | {side['scans_received']} "
            f"| {_f(side['cpu_us_per_msg'], '.1f')} "
            f"| {_f(side['cpu_us_per_msg_to_exit'], '.1f')} | {side['violations']} |"
        )
    out += [
        "",
        f"CPU per message with the scan {_f(sc['cpu_diff_pct'], '+.1f')} %, loss "
        f"{sc['loss_pct_diff']:+.2f} points, CPU added per scan taken "
        f"{_f(sc['cpu_us_per_scan_added'], '.0f')} us (one run each).",
        "",
        f"| in this process, {sc['reduction']['scans']} scans | p50 us | p90 us | p99 us "
        "| max us | mean us |",
        "| --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for label, st in _reduction_rows(sc):
        out.append(
            f"| {label} | {st['p50']:.2f} | {st['p90']:.2f} | {st['p99']:.2f} "
            f"| {st['max']:.2f} | {st['mean']:.2f} |"
        )
    return out


def _md_scale(r: dict[str, Any]) -> list[str]:
    """The Markdown of ``bench --out``'s Scaling section."""
    out: list[str] = []
    sc = r["scale"]
    ref = sc["reference"]
    out += [
        "",
        f"## Scaling (generated configs over 50 inputs, seed {sc['seed']}; daemon at "
        f"{sc['offered']:g} msg/s for {sc['seconds']:g} s)",
        "",
        "| " + " | ".join(SCALE_HEAD) + " |",
        "| " + " | ".join("---:" for _ in SCALE_HEAD) + " |",
    ]
    out += ["| " + " | ".join(cells) + " |" for cells in _scale_rows(sc)]
    for row in sc["rows"]:
        c = row["check"]
        out += ["", f"`check` of {row['requirements']}: {_check_text(c)}; `{c['last']}`", ""]
        out += ["```", *c["analysis"], "```"] if c["analysis"] else []
    out += [
        "",
        f"The daemon on `{ref['config']}` ({ref['topics']} topics) at {ref['offered']:g} "
        f"msg/s: RSS {_mb(ref['rss_start_kb'])} MB once ready, {_mb(ref['rss_end_kb'])} MB "
        f"at the end (HWM {_mb(ref['hwm_end_kb'])} MB), CPU "
        f"{_f(ref['cpu_us_per_msg'], '.1f')} us/msg, lost {ref['lost']}.",
    ]
    return out


def _md_soak(r: dict[str, Any]) -> list[str]:
    """The Markdown of ``bench --out``'s Soak section."""
    out = ["", "## Soak", "", *_format_soak(r["soak"])]
    return out


def _md_latency(r: dict[str, Any]) -> list[str]:
    """The Markdown of ``bench --out``'s Latency section."""
    out: list[str] = []
    lat = r["latency"]
    out += [
        "",
        f"## Latency: trigger published -> halt received ({lat['trials']} trials)",
        "",
        "| what | n | p50 ms | p90 ms | p99 ms | max ms | mean ms | missed |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    d = lat["daemon"]
    before = lat.get("daemon_before_action")
    rows = [("bare rclpy echo", lat["echo"]), ("safety-supervisor (after_publish)", d)]
    if before is not None:
        rows.append(("safety-supervisor (before_action)", before))
    rows += [
        ("daemon: trigger -> violation record", d["trigger_to_record_ms"]),
        ("daemon: detection -> halt published", d["detect_to_publish_ms"]),
    ]
    if before is not None:
        rows.append(("before_action: detection -> halt", before["detect_to_publish_ms"]))
    rows.append((f"fsync of {lat['fsync']['bytes']} bytes", lat["fsync"]))
    for label, st in rows:
        out.append(
            f"| {label} | {st.get('n', '')} | {_f(st['p50'], '.3f')} | {_f(st['p90'], '.3f')} "
            f"| {_f(st['p99'], '.3f')} | {_f(st['max'], '.3f')} | {_f(st['mean'], '.3f')} "
            f"| {st.get('missed', '')} |"
        )
    out += ["", *_durability_goals(lat)]
    out += _breakdown_markdown(lat)
    return out


def _md_replay(r: dict[str, Any]) -> list[str]:
    """The Markdown of ``bench --out``'s Replay throughput section."""
    out: list[str] = []
    rep = r["replay"]
    out += [
        "",
        f"## Replay throughput ({rep['messages']} messages per bag)",
        "",
        "| case | messages | ticks | violations | seconds | msg/s | bag MB |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for c in rep["cases"]:
        out.append(
            f"| {c['case']} | {c['messages']} | {c['ticks']} | {c['violations']} "
            f"| {c['seconds']:.3f} | {c['rate']:.0f} | {c['bag_mb']:.1f} |"
        )
    if rep.get("by_storage"):
        out += ["", "| storage (bulk stepping) | msg/s |", "| --- | --- |"]
        out += [f"| {_STORAGE[k]} | {_rate_range(v)} |" for k, v in rep["by_storage"].items()]
    out += ["", "| monitor alone | per second |", "| --- | ---: |"]
    out += [f"| {k} | {v:.0f} |" for k, v in rep["monitor"].items()]
    return out


# The sections of ``bench --out``'s Markdown, in their order.
_MD_SECTIONS: tuple[tuple[str, Callable[[dict[str, Any]], list[str]]], ...] = (
    ("throughput", _md_throughput),
    ("recording", _md_recording),
    ("ui", _md_ui),
    ("scan", _md_scan),
    ("scale", _md_scale),
    ("soak", _md_soak),
    ("latency", _md_latency),
    ("replay", _md_replay),
)


def _format_throughput(rows: list[dict[str, Any]]) -> list[str]:
    lines = [
        "Throughput and overhead (thesis sec. 5.1.1, eq. 1: "
        "(P_standalone - P_monitor) / P_monitor x 100 %)",
        f"one publisher process, reliable + volatile, depth {DEPTH}, same stream to every receiver",
    ]
    for row in rows:
        per = next(iter(row["sent_per_topic"].values()))
        burst = row.get("burst") or 0
        lines += [
            "",
            f"offered {row['offered']:g} msg/s"
            + (f" in bursts of {burst} rounds" if burst else ", evenly paced")
            + f": sent {row['sent']} ({per}/topic) in "
            f"{row['seconds']:.2f} s = {row['achieved']:.0f} msg/s achieved"
            + ("" if row["drained"] else "  [receivers still busy after 30 s]"),
            f"  {'receiver':<16} {'received':>9} {'loss %':>7} {'msg/s':>8} {'CPU s':>6} "
            f"{'CPU us/msg':>10}",
        ]
        for name, rc in row["receivers"].items():
            lines.append(
                f"  {name:<16} {rc['received']:>9} {rc['loss_pct']:>7.2f} "
                f"{rc['msg_per_s']:>8.0f} {rc['cpu_s']:>6.2f} {_f(rc['cpu_us_per_msg'], '.1f'):>10}"
            )
        lines.append(
            f"  daemon: longest gap between WATCHDOG=1 pings {_f(row.get('longest_ping_gap_ms'), '.0f')}"
            f" ms (WATCHDOG_USEC={row.get('watchdog_usec')})"
        )
        lines.append(_format_loss(row))
        lines.append(
            f"  overhead (eq. 1) vs {row['fastest_baseline']}: {_f(row['overhead_pct'])} %"
            + (
                f"; daemon reported {row['daemon_violations']} violations (expected 0)"
                if row["daemon_violations"]
                else ""
            )
        )
    base = {k for row in rows for k in row["receivers"] if k != "daemon"}
    lines += ["", "summary"]
    head = f"  {'burst':>5} {'offered':>8} {'achieved':>8} {'daemon loss %':>13}"
    for b in sorted(base):
        head += f" {b + ' loss %':>21}"
    head += f" {'overhead %':>10} {'daemon us/msg':>13} {'wait-set us/msg':>15} {'ping gap ms':>11}"
    lines.append(head)
    for row in rows:
        rc = row["receivers"]
        line = (
            f"  {row.get('burst') or '-':>5} {row['offered']:>8g} {row['achieved']:>8.0f}"
            f" {rc['daemon']['loss_pct']:>13.2f}"
        )
        for b in sorted(base):
            line += f" {_f(rc[b]['loss_pct'] if b in rc else None):>21}"
        ws = rc.get("rclpy wait-set", {}).get("cpu_us_per_msg")
        line += (
            f" {_f(row['overhead_pct']):>10} {_f(rc['daemon']['cpu_us_per_msg'], '.1f'):>13}"
            f" {_f(ws, '.1f'):>15} {_f(row.get('longest_ping_gap_ms'), '.0f'):>11}"
        )
        lines.append(line)
    return lines


def _format_loss(row: dict[str, Any]) -> str:
    """sent - received of the daemon, split as docs/reference/commands.md#bench says."""
    loss = row["daemon_loss"]
    # Not drained: what is above the last number taken may still have been on its way.
    tail = "after the last taken" if row["drained"] else "not yet taken (or after the last)"
    return (
        f"  daemon: sent - received {loss['missing']} = counted lost {loss['gaps']}"
        f" + before the first heard {loss['before_first']} + {tail} {loss['after_last']}"
        + ("" if loss["agree"] else "  [DISAGREE]")
    )


def _breakdown_markdown(lat: dict[str, Any], key: str = "breakdown") -> list[str]:
    """The daemon's stages as a table (``key``: which breakdown)."""
    b = lat.get(key)
    if not b:
        return []
    idle = lat.get(f"{key}_idle") or {}
    cold = idle.get("stages_us", {})
    head = f"after {idle['idle_ms']:g} ms idle p50 µs" if idle else "after idle"
    out = [
        "",
        f"The daemon's stages in one process, durability {b.get('durability', 'before_action')}"
        f", {b['trials']} violations back to back"
        + (f" and {idle['trials']} after {idle['idle_ms']:g} ms idle each" if idle else "")
        + ":",
        "",
        f"| stage | p50 µs | p99 µs | max µs | {head} | what |",
        "| --- | ---: | ---: | ---: | ---: | --- |",
    ]
    for name, st in b["stages_us"].items():
        c = cold.get(name, {}).get("p50")
        out.append(
            f"| {name} | {_f(st['p50'], '.1f')} | {_f(st['p99'], '.1f')} | {_f(st['max'], '.1f')} "
            f"| {_f(c, '.1f') if c is not None else ''} | {st['what']} |"
        )
    t = b["total_us"]
    c = idle.get("total_us", {}).get("p50")
    out.append(
        f"| total | {_f(t['p50'], '.1f')} | {_f(t['p99'], '.1f')} | {_f(t['max'], '.1f')} "
        f"| {_f(c, '.1f') if c is not None else ''} | |"
    )
    if "after_halt_us" in b:
        a = b["after_halt_us"]
        out.append(
            f"| (after the halt) | {_f(a['p50'], '.1f')} | {_f(a['p99'], '.1f')} "
            f"| {_f(a['max'], '.1f')} | | {a['what']} |"
        )
    if key == "breakdown":
        out += _breakdown_markdown(lat, "breakdown_after_publish")
    return out


def _format_breakdown(lat: dict[str, Any], fs: dict[str, Any], key: str = "breakdown") -> list[str]:
    """The daemon's stages (``key``: which breakdown)."""
    b = lat.get(key)
    if not b:
        return []
    idle = lat.get(f"{key}_idle")
    lines = [
        f"  the daemon's stages, durability {b.get('durability', 'before_action')}, in one "
        f"process ({b['trials']} violations back to back"
        + (f"; after {idle['idle_ms']:g} ms idle: {idle['trials']} more" if idle else "")
        + "), µs:"
    ]
    for name, st in b["stages_us"].items():
        cold = (idle or {}).get("stages_us", {}).get(name)
        after = f"  idle p50 {_f(cold['p50'], '.1f'):>7}" if cold else ""
        lines.append(
            f"    {name:<11} p50 {_f(st['p50'], '.1f'):>7}  p99 {_f(st['p99'], '.1f'):>7}  "
            f"max {_f(st['max'], '.1f'):>8}{after}  {st['what']}"
        )
    t = b["total_us"]
    after = f"  idle p50 {_f(idle['total_us']['p50'], '.1f'):>7}" if idle else ""
    lines.append(
        f"    {'total':<11} p50 {_f(t['p50'], '.1f'):>7}  p99 {_f(t['p99'], '.1f'):>7}  "
        f"max {_f(t['max'], '.1f'):>8}{after}"
    )
    if "after_halt_us" in b:
        a = b["after_halt_us"]
        lines.append(
            f"    {'(after)':<11} p50 {_f(a['p50'], '.1f'):>7}  p99 {_f(a['p99'], '.1f'):>7}  "
            f"max {_f(a['max'], '.1f'):>8}  {a['what']}"
        )
    if key == "breakdown":
        lines += _format_breakdown(lat, fs, "breakdown_after_publish")
    return lines


def _ratio(a: float | None, b: float | None) -> str:
    return "n/a" if a is None or b is None or b <= 0 else f"{a / b:.2f}x"


def _durability_goals(lat: dict[str, Any]) -> list[str]:
    """The halt-latency goals of each logging.durability (docs/reference/log.md):
    after_publish against the DDS echo alone, before_action against echo + fsync."""
    echo, d, fs = lat["echo"], lat["daemon"], lat["fsync"]
    lines = [
        f"after_publish: halt p50 {_f(d['p50'], '.3f')} ms = {_ratio(d['p50'], echo['p50'])} "
        f"the echo p50 (goal: at most 1.3x); p99 {_f(d['p99'], '.3f')} ms = "
        f"{_ratio(d['p99'], echo['p99'])} the echo p99 (goal: at most 1.5x)"
    ]
    before = lat.get("daemon_before_action")
    if before is not None and echo["p50"] is not None and fs["p50"] is not None:
        floor = echo["p50"] + fs["p50"]
        lines.append(
            f"before_action: floor (echo p50 + fsync p50) {floor:.3f} ms; halt p50 "
            f"{_f(before['p50'], '.3f')} ms = {_ratio(before['p50'], floor)} the floor "
            "(goal: at most 1.3x)"
        )
    rounds = lat.get("rounds") or []
    if len(rounds) > 1:  # each round's own p50s: how far the machine drifted
        each = "; ".join(
            f"echo {_f(r['echo_p50'], '.3f')}, after_publish {_f(r['daemon_p50'], '.3f')} "
            f"({_ratio(r['daemon_p50'], r['echo_p50'])})"
            for r in rounds
        )
        lines.append(f"p50 ms of each of the {len(rounds)} rounds pooled above: {each}")
    return lines


def _format_latency(lat: dict[str, Any]) -> list[str]:
    lines = [
        "Latency: violating trigger published -> halt received, in one process "
        f"(time.monotonic_ns); {lat['trials']} trials after {lat['warmup']} warm-up",
        f"  {'responder':<22} {'n':>5} {'p50 ms':>7} {'p90 ms':>7} {'p99 ms':>7} {'max ms':>7} "
        f"{'mean ms':>7} {'missed':>6}",
    ]
    runs = [("bare rclpy echo", "echo"), ("supervisor after_publish", "daemon")]
    runs += [("supervisor before_action", "daemon_before_action")]
    for label, key in runs:
        st = lat.get(key)
        if st is None:  # a result from before the durability runs
            continue
        lines.append(
            f"  {label:<22} {st['n']:>5} {_f(st['p50'], '.3f'):>7} {_f(st['p90'], '.3f'):>7} "
            f"{_f(st['p99'], '.3f'):>7} {_f(st['max'], '.3f'):>7} {_f(st['mean'], '.3f'):>7} "
            f"{st['missed']:>6}"
        )
    d = lat["daemon"]
    inner = d["detect_to_publish_ms"]
    rec = d["trigger_to_record_ms"]
    lines += [
        f"  daemon, trigger published -> violation record stamped (before its fsync): p50 "
        f"{_f(rec['p50'], '.3f')} ms, p99 {_f(rec['p99'], '.3f')} ms, max {_f(rec['max'], '.3f')} ms",
        f"  daemon, detection -> halt published (its mitigation records): p50 "
        f"{_f(inner['p50'], '.3f')} ms, p99 {_f(inner['p99'], '.3f')} ms, "
        f"max {_f(inner['max'], '.3f')} ms",
    ]
    fs = lat["fsync"]
    lines.append(
        f"  fsync of a {fs['bytes']}-byte append on the log's file system ({fs['n']} samples): "
        f"p50 {_f(fs['p50'], '.3f')} ms, p99 {_f(fs['p99'], '.3f')} ms, "
        f"max {_f(fs['max'], '.3f')} ms"
    )
    lines += ["  " + g for g in _durability_goals(lat)]
    lines += _format_breakdown(lat, fs)
    if (
        d["other_violations"]
        or d["stray_halts"]
        or lat["echo"]["stray_halts"]
        or d["not_from_holding_state"]
        or d["sync_timeouts"]
        or lat["echo"]["sync_timeouts"]
    ):
        lines.append(
            f"  note: {d['other_violations']} violations of other requirements, "
            f"{d['not_from_holding_state']} trials not stepped from the nominal state, stray "
            f"halts {lat['echo']['stray_halts']} (echo) / {d['stray_halts']} (daemon) while "
            f"settling, handshake timeouts {lat['echo']['sync_timeouts']} / {d['sync_timeouts']}"
        )
    mean = d["mean"]
    cmp = "" if mean is None else f" ({THESIS_MEAN_MS / mean:.0f}x faster than the thesis's mean)"
    lines.append(
        f"  thesis: {THESIS_MEAN_MS:g} ms mean (OGMA/Copilot node), TeSSLa-ROS-Bridge "
        f"{TESSLA_MEAN_MS:g} ms mean; here: {_f(mean, '.3f')} ms mean{cmp}"
    )
    return lines
