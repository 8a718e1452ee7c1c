"""The hardware bridge: RRG's arm/hand interface on a real Barrett WAM, BarrettHand and Nano17s."""
