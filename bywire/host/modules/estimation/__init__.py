"""The host's estimation: where the car is and what is around it (odometry, the radar's lead vehicle, the
GPS/INS pose, the cooperative world model). Computing modules: pure functions of their inputs, replayed
exactly from a recording."""
