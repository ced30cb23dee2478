"""Which score field goes where: the correction core's results <-> PullScore / SetSummary messages.

PullScore carries the core's PullScoreResult fields under the same names; SetSummary renames the
core's SetSummary fields (``SET_SUMMARY_FIELDS``: message field -> core attribute).
"""

PULL_SCORE_FIELDS = ('stationary_peak_n', 'raw_peak_n', 'corrected_peak_n', 'filtered_peak_n',
                     'raw_diff_pct', 'corrected_diff_pct', 'filtered_diff_pct',
                     'raw_rms_n', 'corrected_rms_n', 'filtered_rms_n')

SET_SUMMARY_FIELDS = {
    'pulls': 'pulls',
    'stationary_peak_mean_n': 'mean_stationary_peak_n',
    'raw_diff_mean_pct': 'raw_mean_pct', 'raw_diff_std_pct': 'raw_std_pct',
    'corrected_diff_mean_pct': 'corrected_mean_pct', 'corrected_diff_std_pct': 'corrected_std_pct',
    'filtered_diff_mean_pct': 'filtered_mean_pct', 'filtered_diff_std_pct': 'filtered_std_pct',
}
