"""The simulator side: the Genesis twin of a world, motion planning (IK + OMPL RRTConnect) and the scripted
tasks (grasp, press, push/pull). Knows no datasets or file formats (DESIGN.md section 4)."""
