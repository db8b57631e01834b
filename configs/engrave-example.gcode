; engrave-example.gcode: a border, a diagonal and a short zig-zag engraved 0.1 mm deep into the
; plate of configs/sim-cell.yaml, written for a perfectly flat, level plate at Z = 0 (mm).
G21 G90 G17          ; mm, absolute, XY plane
G0 Z5.0              ; safe height
G0 X-150.0 Y-120.0   (start corner)
G1 Z-0.1 F100        ; plunge
G1 X150.0 F600       ; border: modal Y, Z
Y120.0
X-150.0
Y-120.0
G0 Z5.0
G0 X-150.0 Y120.0
G1 Z-0.1 F100
G1 X150.0 Y-120.0 F600  ; the long diagonal
G0 Z5.0
G0 X-100.0 Y-60.0
G1 Z-0.1 F100
G1 X-80.0 Y-40.0 F600
G1 X-60.0 Y-60.0
G1 X-40.0 Y-40.0
G0 Z5.0
M2
