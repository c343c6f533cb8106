"""softgrip_calibrate --live: the gripper holds each pressure in turn while you measure.

Through the running controller's grasp manager (an OPEN goal of the ``grasp`` action that holds
``open_pressure_pa``): once it reports ENVELOPED (settled), the pressure recorded is the mean of
the estimator's pressure over the next half second, and you type what you measured. Every row is
appended to the CSV at once, so a stop loses nothing measured. At the end, on Ctrl-C or on a
failure the gripper is stopped (vented).
"""
from __future__ import annotations

import csv
import math
import pathlib
import time

SETTLE_TIMEOUT_S = 20.0
AVERAGE_S = 0.5


class LiveStopped(Exception):
    """The live run stopped: the reason, said to the user."""


def parse_pressures(text: str) -> list:
    try:
        pressures = [float(p) for p in text.split(",") if p.strip()]
    except ValueError:
        raise ValueError(f"--pressures {text!r}: a comma-separated list of Pa") from None
    if not pressures or any(not (math.isfinite(p) and p > 0.0) for p in pressures):
        raise ValueError(f"--pressures {text!r}: give one or more positive pressures in Pa "
                         "(positive pressure opens the fingers; the model is fitted there)")
    return pressures


def ask(prompt: str, read=input):
    """A number or None (empty); asks again on anything else. EOFError propagates."""
    while True:
        text = read(prompt).strip()
        if not text:
            return None
        try:
            value = float(text)
        except ValueError:
            print(f"  not a number: {text!r}; again, or empty if not measured")
            continue
        if math.isfinite(value):
            return value
        print("  a finite number, please")


def measure(pressures: list, columns: list, record: pathlib.Path, namespace: str = "",
            read=input, progress=print) -> pathlib.Path:
    """Hold each pressure, ask for each column, append the rows to ``record`` (CSV)."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions
    from softgrip_interfaces.msg import GripperState
    from softgrip_ros.client import GripperClient
    # rclpy's own SIGINT handler would shut the context down before the stop below could vent:
    # a Ctrl-C is Python's KeyboardInterrupt here
    context = rclpy.Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    client = GripperClient(namespace=namespace, node_name="softgrip_calibrate", context=context)
    try:
        if not client.wait_until_ready(10.0):
            raise ConnectionError(f"no gripper answered on {namespace or '/'}grasp within 10 s: "
                                  "is the controller running?")
        new = not record.exists() or record.stat().st_size == 0
        with record.open("a", newline="") as handle:
            writer = csv.writer(handle)
            if new:
                writer.writerow(["pressure_pa", *columns])
            for index, target in enumerate(pressures, start=1):
                progress(f"[{index}/{len(pressures)}] holding {target / 1e3:.1f} kPa ...")
                if not client.open(tip_spacing_m=0.0, pressure_pa=target):
                    raise LiveStopped(f"the gripper refused {target:.0f} Pa: "
                                      f"{client.state().message}")
                # this goal's own end (the last grasp_state may still be the previous hold's)
                deadline = time.monotonic() + SETTLE_TIMEOUT_S
                while not client.is_task_complete():
                    if time.monotonic() > deadline:
                        raise LiveStopped(f"{target:.0f} Pa not reached in {SETTLE_TIMEOUT_S:g} "
                                          f"s: {client.state().message}")
                    time.sleep(0.02)
                result = client.result()
                if result is None or result.final_phase != GripperState.ENVELOPED:
                    raise LiveStopped(f"{target:.0f} Pa not reached: "
                                      f"{result.message if result else 'no result'}")
                time.sleep(0.2)  # grasp_state is its own topic: past the previous hold's
                samples, end = [], time.monotonic() + AVERAGE_S
                while time.monotonic() < end:
                    samples.append(client.state().estimated_gauge_pressure_pa)
                    time.sleep(0.02)
                pressure = sum(samples) / len(samples)
                progress(f"  measure now: the estimate is {pressure / 1e3:.2f} kPa")
                values = [ask(f"  {column}: ", read) for column in columns]
                writer.writerow([f"{pressure:.1f}", *("" if v is None else f"{v:.9g}"
                                                      for v in values)])
                handle.flush()
    finally:
        try:
            if client.state() is not None:
                client.stop()
                progress("stopped: the gripper vents")
        finally:
            client.close()
            rclpy.try_shutdown(context=context)
    return record
