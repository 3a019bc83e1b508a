"""Position control: the controllers (pid, lqg), stepping them sample by sample (stepper, with
its compiled step_kernel), and the closed loop (stability, sensitivity, robustness)."""
