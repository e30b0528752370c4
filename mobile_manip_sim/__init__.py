"""mobile_manip_sim: a nonholonomic mobile manipulator with revolute–prismatic arm joints,
simulated with a recursive Gibbs–Appell dynamics core (see README.md)."""

__version__ = "0.1.0"
