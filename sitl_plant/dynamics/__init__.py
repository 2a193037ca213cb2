"""Pure quadrotor dynamics: no sockets, files, clocks or logging in this package."""
