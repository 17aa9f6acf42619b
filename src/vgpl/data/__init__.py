"""HDF5 datasets of particle trajectories and rendered video."""
