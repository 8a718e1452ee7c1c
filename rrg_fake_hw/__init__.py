"""Emulated WAM, BarrettHand and Net F/T drivers on the MuJoCo world: test doubles of the real
drivers below rrg_hw_bridge.ros.bridge_node, speaking their protocols (``rrg-fake-hw``)."""
