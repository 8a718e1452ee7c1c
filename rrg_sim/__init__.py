"""The simulated world: the geometric and MuJoCo simulators, the world profiles, the robot-side
WRT executor, and the simulator node."""
