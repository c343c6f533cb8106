"""Small pieces every softgrip node uses: the spin-and-exit-cleanly main, CAN bus opening, stamps."""
from __future__ import annotations

import faulthandler
import signal
import sys

import can
import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException

P_ATM_PA = 101_325.0


def open_bus(interface: str, channel: str, bitrate: int) -> can.BusABC:
    """A python-can bus; the virtual and softgrip_ipc interfaces take no bitrate."""
    kwargs = {} if interface in ("virtual", "softgrip_ipc") else {"bitrate": bitrate}
    return can.Bus(interface=interface, channel=channel, **kwargs)


def run_node(node_factory, args=None) -> int:
    """rclpy.init, build the node, spin until SIGINT/SIGTERM, then ``node.close()`` (vent) and exit 0.

    rclpy (Jazzy) handles SIGTERM as it does Ctrl-C, waking the executor, so the node's close
    runs and no traceback is printed. (A Python-level handler would not run while spin waits
    in C on a node without timers.) A node that fails to start prints its reason and returns 1.
    """
    rclpy.init(args=args)   # rclpy's own handlers turn SIGINT and SIGTERM into a shutdown that wakes spin
    faulthandler.register(signal.SIGUSR1, all_threads=True)   # kill -USR1 <pid>: where is every thread?
    try:
        node = node_factory()
    except (ValueError, ParameterException) as error:   # a bad parameter at start-up: say which, exit 1
        print(f"{sys.argv[0]}: {error}", file=sys.stderr)
        rclpy.try_shutdown()
        return 1
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        # A signal landing while spin builds its wait set surfaces as RCLError ("context is
        # not valid") instead of ExternalShutdownException: that is the same shutdown.
        if rclpy.ok():
            raise
    finally:
        node.close()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
