"""mobile_manip_sim: a nonholonomic mobile manipulator with revolute–prismatic arm joints,
simulated with a recursive Gibbs–Appell dynamics core (see README.md and docs/)."""

__version__ = "0.1.0"
