"""ATI Net F/T force/torque sensor: its CAN bus protocol (:mod:`.protocol`) and driver
(:mod:`.can_driver`)."""
