"""Machine stage: kinematics, rotary schedules, poses along the paths, reachability."""
