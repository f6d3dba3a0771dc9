"""What the ground sends a running vehicle: perturbations as acknowledged Zenoh requests
(``perturb``), QGroundControl plans over the MAVLink mission protocol (``plan``).
May import ``ground.record`` and ``ground.scenario``."""
