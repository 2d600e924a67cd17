"""Flight-controller side: maneuvers, dead reckoning, MAVLink, the link to the receiver."""
