"""How good the estimates are: every reported figure's key, label and target (``metric_table``), scoring a
run against the truth and the tables (``scoring``), contact accuracy (``contact_accuracy``), identification
accuracy (``identification_accuracy``), the sensor-count study (``sensor_subsets``), the ablation's variants
(``ablation_variants``), the simulator's fidelity to TACTO (``fidelity``), the autoencoder's latent gaps
(``latent_gaps``), how well a track follows the object (``tracking_accuracy``), the report's figures
(``plots``), and two studies' references: what any estimator loses to the sensor poses' error
(``kinematic_bound``) and which wrong estimates the touched surface cannot tell from the truth (``symmetry``).

Layer 7 of 8: imports every layer below it.
"""
