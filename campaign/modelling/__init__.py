"""``campaign model``: a whole JSBSim aircraft from an identification (metrics, mass, flight controls
taking the logged surfaces, the identified aerodynamics, the measured thrust as an external force),
and the steady flight of such an aircraft."""
