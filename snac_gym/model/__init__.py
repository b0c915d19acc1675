"""The arm's model: its kinematics (Pinocchio), the robots and UR models it is built from, the joint limits, an
in-limit IK goal, and the rigid errors a controller's model can have."""
