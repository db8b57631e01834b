; engrave-example.gcode: a border, a diagonal and a short zig-zag engraved 0.1 mm deep into the
; plate of configs/sim-cell.yaml, written for a perfectly flat, level plate at Z = 0 (mm).
G21 G90 G17          ; mm, absolute, XY plane
G0 Z5.0              ; safe height
G0 X-150 Y-120       (start corner)
G1 Z-0.1 F100        ; plunge
G1 X150 F600         ; border: modal Y, Z
Y120
X-150
Y-120
G0 Z5.0
G0 X-150 Y120
G1 Z-0.1 F100
G1 X150 Y-120 F600   ; the long diagonal
G0 Z5.0
G0 X-100 Y-60
G1 Z-0.1 F100
G1 X-80 Y-40 F600
G1 X-60 Y-60
G1 X-40 Y-40
G0 Z5.0
M2
