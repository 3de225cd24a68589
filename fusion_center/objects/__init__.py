"""Short-range object characterization and recognition (Section 7 of the CoLOR chapter).

Pure numpy: pulse separation (:mod:`.pulses`), fuzzy RPM imaging (:mod:`.fuzzy`),
polarimetry and ellipsometry (:mod:`.material`), CSS recognition (:mod:`.recognition`) and
the reference alphabet (:mod:`.alphabet`).
"""
