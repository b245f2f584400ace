"""The closed loop: the controller law the firmware and the sim node run, its design on an identified model
against a performance template, the transient metrics, and the check of a closed-loop record.

=================  ===========================================================================================
``law``            the discrete PID + feedforward law (one definition; the firmware's C copy is tested against it)
``feedforward``    the static duty that holds an angle under a model (the law's feedforward)
``metrics``        step-response metrics (rise, overshoot, settling, steady-state error, peak duty) and templates
``loop``           closed-loop simulation of a model with the law: the rig simulator's code, sample by sample
``design``         gains for a template on a model (linearisation, search, nonlinear check), the gains YAML
``check``          measured vs predicted transients of a closed-loop record
=================  ===========================================================================================
"""
