"""Reading a campaign CSV keeps no memory it does not need: pyarrow's columns come out as numpy's own arrays
without importing pandas (pyarrow's to_numpy does: ~60 MB of every discover worker), and the parse's pages go back."""
import json
import subprocess
import sys

import numpy as np

from bag_tools.core.daqfiles import read_csv


def test_csv_columns_without_pandas_and_nulls_as_nan(tmp_path):
    path = tmp_path / 'pull.csv'
    rows = ['time_s,force_moving_n,force_stationary_n'] + [
        f'{i * 2e-5!r},{float(np.sin(i / 7.0))!r},{i if i % 5 else ""}' for i in range(120_000)]
    path.write_text('\n'.join(rows) + '\n')
    code = ('import json, sys\n'
            'from pathlib import Path\n'
            'from bag_tools.core.daqfiles import read_csv\n'
            f'cols = read_csv(Path({str(path)!r}))\n'
            'print(json.dumps(["pandas" in sys.modules, all(c.flags.owndata for c in cols.values())]))')
    pandas_loaded, owned = json.loads(subprocess.run([sys.executable, '-c', code], check=True, capture_output=True,
                                                     text=True).stdout)
    assert not pandas_loaded, 'reading a CSV imported pandas'
    assert owned, "the columns still point into pyarrow's buffers"
    cols = read_csv(path)
    i = np.arange(120_000)
    assert np.array_equal(cols['force_moving_n'], np.sin(i / 7.0))
    want = np.where(i % 5 == 0, np.nan, i.astype(float))
    assert np.array_equal(cols['force_stationary_n'], want, equal_nan=True)
