"""The simulated Velodyne HDL-64E (seed 000 Sec. 2.3, 4 and 6): the urban world as triangles, cast by
Embree, one `host.perception.scan.Scan` per revolution.

`mesh` (triangles tagged with their surface, the ground plane), `road_marks` (lane paint and curbs of an
RNDF network), `scene` (the ray-casting scene: static once, moving cars per revolution), `velodyne` (the
sensor model), `urban_scene` (an `UrbanWorld` as a scene, `UrbanLidar`), `bench` (one revolution's cast
for the benchmarks). The scans cross to the host in `bywire.protocol.lidar.scan_message`'s format (`wire`).
"""
