"""The grasp sensing's motion judgements in a child process of its own (nothing heavy imported
at the top: see :mod:`softgrip_ros.runtime.worker_process`)."""
from __future__ import annotations

from concurrent.futures import Future

from softgrip_ros.runtime.worker_process import WorkerProcess, worker_state

# a judgement has a deadline (the grasp manager's sensing_wait): at the workers' +10, beside busy
# processes at nice 0 it got a tenth of a core and its start-up and first verdict never came in
# time; at +5 it still yields to the control loop
JUDGE_NICE_INCREMENT = 5


class MotionJudgeProcess:
    """:func:`~softgrip_ros.estimation.grasp_sensing.judge_motion` in a child (a
    :class:`WorkerProcess`) that builds its own contact model with
    :func:`~softgrip_ros.estimation.grasp_sensing.contact_model_for` (``gripper_model``,
    ``bending``, ``plant_parameters``, ``bending_volume_share``: the plant file's, or None).
    A judgement is CPU-heavy numpy and Python: in a thread of the composed controller it would
    hold the GIL the control loop and an in-process simulated device need. :meth:`close` it when
    done."""

    def __init__(self, gripper_model: str, bending: str, plant_parameters,
                 bending_volume_share: float | None = None,
                 nice_increment: int = JUDGE_NICE_INCREMENT):
        self._worker = WorkerProcess(
            _setup_judge, (gripper_model, bending, plant_parameters, bending_volume_share),
            nice_increment, "softgrip-sensing")

    def submit(self, job) -> Future:
        """The verdict on the MotionJob ``job`` (a Detection), as a future; the model's build or
        the judgement's error through the future."""
        return self._worker.submit(_judge_in_worker, job)

    def close(self) -> None:
        self._worker.close()


def _setup_judge(gripper_model: str, bending: str, plant_parameters,
                 bending_volume_share: float | None):
    from softgrip_ros.estimation.grasp_sensing import contact_model_for
    return contact_model_for(gripper_model, bending, plant_parameters, bending_volume_share)


def _judge_in_worker(job):
    from softgrip_ros.estimation.grasp_sensing import judge_motion
    return judge_motion(worker_state(), job)
