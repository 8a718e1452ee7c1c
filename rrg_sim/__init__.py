"""The simulated world: the WAM, the BarrettHand, the objects and the goal model, the geometric
and MuJoCo simulators, the robot-side WRT executor, and the simulator node."""
