"""The simulated station: the iiwa 7, the WSG-50 gripper and the cupboard (doorlab's cell)."""

from doorlab.pset.handout.station_api import StationRun, shared_meshcat


class ManipulationStationSimulator:
    """Runs plans on the simulated station, on the original timeline.

    ``RunSimulation`` holds ``q0_iiwa`` for 2 s, moves in 7 s to the start of the first plan
    (which must be a JointSpacePlan), then runs each plan for its duration plus 1 s, then
    ``extra_time`` [s]. Logs are sampled every 0.01 s.
    """

    def __init__(self):
        self._run = StationRun()
        self.result = None  # the last episode's doorlab.EpisodeResult (all named logs)

    def RunSimulation(
        self,
        q0_iiwa,
        door_angles,
        plan_list,
        gripper_setpoint_list,
        extra_time=0,
        real_time_rate=1.0,
        is_visualizing=True,
        gripper_setpoint_initial=0.025,
    ):
        """Simulates the plans; door_angles = (left, right) hinge angles [rad] at t = 0.

        Returns:
            (iiwa_position_command_log, iiwa_position_measured_log, iiwa_external_torque_log,
            iiwa_velocity_estimated_log, plant_state_log, t_plan): logs with ``.data()``
            (channels x samples) and ``.sample_times()`` [s]; plant_state_log holds the whole
            plant's positions; t_plan the start time of every plan (the hold and the move
            first) and the end of the last [s].
        """
        meshcat = shared_meshcat() if is_visualizing else None
        logs = self._run.run(
            q0_iiwa,
            door_angles,
            list(plan_list),
            list(gripper_setpoint_list),
            extra_time=extra_time,
            real_time_rate=real_time_rate,
            meshcat=meshcat,
            gripper_setpoint_initial=gripper_setpoint_initial,
        )
        self.result = self._run.result
        return logs

    def RunRealRobot(
        self, plan_list, gripper_setpoint_list, extra_time=2.0, lcm_url=None, wait=5.0, yes=False
    ):
        """Runs the plans on the real arm over LCM, from where it stands (``doorlab run
        --hardware``'s path: it prints the plan and asks first; every command is checked).

        ``lcm_url``: the drivers' LCM URL (default Drake's); ``wait``: seconds to wait for the
        driver; ``yes``: do not ask. Returns (iiwa_position_command_log,
        iiwa_position_measured_log, iiwa_velocity_estimated_log, iiwa_external_torque_log,
        t_plan), as in 2019.
        """
        try:
            return self._run.run_real_robot(
                list(plan_list),
                list(gripper_setpoint_list),
                extra_time=extra_time,
                lcm_url=lcm_url,
                wait=wait,
                yes=yes,
            )
        finally:
            self.result = self._run.result


def StartMeshcat():
    """Drake's Meshcat for this kernel (started once; prints its URL). Replaces the 2019
    notebook's standalone ``meshcat.Visualizer()``."""
    return shared_meshcat()
