"""What the law is built on and both processes share (docs/api.md; ../shared/ARCHITECTURE.md).

The controller process (``offboard fly``) imports this and nothing of ``sitl_plant``; the
simulator imports it too, so each idea has one home:

- ``rotations``: quaternions, Euler angles, DCMs, the body-z/yaw attitude;
- ``euler_lagrange``: W_eta (eq. 4), the inertia matrix and eq. 14/16 (``real_torques``);
- ``mixer``: the eq. 9-11 rotor forces of a thrust and torque;
- ``state``: ``VehicleState``; ``vehicle``: vehicle parameters and files;
- ``tomlfile``: the TOML field reader every file format uses; ``errors``: the user-error classes;
- ``px4_modes``: PX4's mode numbers, names and HEARTBEAT custom_mode;
- ``tlog``: the tlog writer; ``paths``: the output-file rules; ``clihelp``: the CLIs' help format.
"""
