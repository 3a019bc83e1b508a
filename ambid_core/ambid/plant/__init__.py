"""The plant: the rig's parameters, its physics and the simulator that runs them.

rig (parameters) -> rotor models (fem_rotor, rigid_rotor, modal, rotor_model,
rotor_import), magnet, amplifier, sensors -> analytical (chapter 2's model)
and true_rig (what the simulator runs) -> simulator (+ its compiled
step_kernel) and levitation (is the rotor up?).
"""
