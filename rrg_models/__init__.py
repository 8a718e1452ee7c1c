"""The robot's models: the WAM, the BarrettHand and its sensing, the objects, world-relative
trajectories, the observation and the goal model, with their constants (ROS-free).

Shared by the simulators, the belief, the planner and the hardware bridge: the WAM's kinematics,
IK paths and feasibility (``wam``, ``trajectory``, ``wam_feasibility``), its MJCF and URDF
(``description``), the hand (``hand``, ``hand_sensing``), the objects (``objects``), the WRTs
(``wrt``), the observation (``observation``), the goal model (``goal``), and the model constants
with their sources (``config``)."""
