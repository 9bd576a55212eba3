"""``clis run``'s progress view ends the run on what the learner wrote, not only on what
reached it: a progress row published before ``clis run``'s subscription was matched is never
delivered (transient local keeps the newest only), and a short run's episodes can all be
learned in that moment."""

from __future__ import annotations

import os
import time

from clis_app.graph.progress import ProgressView


def _append(table, n: int) -> None:
    with open(table, 'a') as fh:
        for k in range(n):
            fh.write(f'innate,{k},1\n')


def test_the_table_ends_the_run_once_each_row_is_checkpointed(tmp_path):
    table = tmp_path / 'episodes.csv'
    table.write_text('label,episode,learned\ninnate,0,1\n')         # a resumed run's row
    view = ProgressView(2, 50, quiet=True, tty=False, table=table)
    assert not view.update([])
    _append(table, 2)
    # the rows are there, the checkpoint of the last one not yet: one episode is not done
    assert view.table_learned == 1 and not view.update([])
    time.sleep(0.01)
    (tmp_path / 'checkpoint.npz').write_bytes(b'x')
    assert view.table_learned == 2 and view.update([])


def test_the_progress_rows_alone_end_it_without_a_table(tmp_path):
    view = ProgressView(2, 50, quiet=True, tty=False)
    rows = [{'episode': '1', 'learned': '1'}, {'episode': '2', 'learned': '0'}]
    assert not view.update(rows)
    assert view.update(rows + [{'episode': '3', 'learned': '1'}])


def test_an_older_checkpoint_does_not_count_the_newest_row(tmp_path):
    table = tmp_path / 'episodes.csv'
    table.write_text('label,episode,learned\n')
    (tmp_path / 'checkpoint.npz').write_bytes(b'x')
    old = time.time_ns() - 10**9
    os.utime(tmp_path / 'checkpoint.npz', ns=(old, old))
    view = ProgressView(1, 50, quiet=True, tty=False, table=table)
    _append(table, 1)
    assert view.table_learned == 0 and not view.update([])
