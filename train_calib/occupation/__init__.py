"""Calibration of the running-time model from track occupation data (Besinovic et al. 2013).

ROS-free core of ``train-calib calibrate-occupation`` and ``simulate-occupation``:

- :mod:`.events`: the occupation/release CSV format and its validating loader;
- :mod:`.generate`: the events a train describer logs for a head trajectory s(t);
- :mod:`.length`: train length from occupation/release (eq. 1-2) and composition assignment;
- :mod:`.unhindered`: the filter that drops runs hindered by other trains, with the reason;
- :mod:`.compositions`: TYPES.yaml (lengths, defaults, calibration bounds);
- :mod:`.objective`, :mod:`.model`, :mod:`.calibrate`: eq. 8 on the simulator's running-time model,
  minimised per run by differential evolution;
- :mod:`.robustness` (Table 3), :mod:`.sensitivity` (fixing c1, r1; identifiability),
  :mod:`.distributions` (MLE fits chosen by KS, Table 4 / Figs. 7-9);
- :mod:`.fleet`: simulated fleets with known truth; :mod:`.pipeline`, :mod:`.report`, :mod:`.plots`.
"""
