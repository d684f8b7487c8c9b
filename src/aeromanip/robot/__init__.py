"""Robot description (spec, TOML, URDF) and its CasADi kinematics."""
