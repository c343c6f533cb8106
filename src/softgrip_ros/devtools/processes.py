"""Running the installed executables as processes: for the demo, the benchmarks and the tests."""
from __future__ import annotations

import os
import signal
import subprocess


def installed_executable(name: str) -> str:
    """``<prefix>/lib/softgrip_ros/<name>``, where ``ros2 run`` finds it."""
    from ament_index_python.packages import get_package_prefix
    return os.path.join(get_package_prefix("softgrip_ros"), "lib", "softgrip_ros", name)


def stop_process(process: subprocess.Popen, timeout_s: float = 10.0) -> int | None:
    """SIGTERM ``process`` (only this one, by its PID) if it still runs, wait, kill it if it will
    not stop; its return code, or None when it had to be killed. Before the kill it gets SIGUSR1:
    the package's executables then print every thread's stack (run_node registers it), which
    says where it hung; anything else ends on it, as it would on the kill."""
    if process.poll() is None:
        process.send_signal(signal.SIGTERM)
        try:
            process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            process.send_signal(signal.SIGUSR1)
            try:
                process.wait(timeout=2.0)
            except subprocess.TimeoutExpired:
                pass
            process.kill()
            process.wait()
            return None
    return process.returncode
