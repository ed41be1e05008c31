"""The board's marks: what the C core copies at a marked address is what a Python probe there reads."""

from __future__ import annotations

import pytest

from steval_link import constants as C
from steval_link.emulation.runner import STEP_RAM, Emulation, EmulationOptions

pytest.importorskip("unicorn")


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_a_mark_holds_what_a_probe_at_the_same_address_reads(reference_elf):
    emu = Emulation(EmulationOptions(elf=reference_elf, scenario="hand-tilts", duration_s=5.0, seed=3))
    b, e = emu.board, emu.elf
    assert b.native, "the C core is built in CI"
    ram = [(e.addr(name), n) for name, n in STEP_RAM]
    probed = []

    def probe(kind):
        def read(board):
            cyccnt = board.scs.cyccnt()
            ram_now = tuple((a, board.ram_read(a, n)) for a, n in ram)
            counters = (board.now, board.instructions_now(), board.exception_instructions, cyccnt)
            probed.append((kind, *counters, ram_now, emu.tick_index()))

        return read

    b.probe(e.addr("ahrs_fusion_ag"), probe(0))  # after the runner's marks at the same addresses
    b.probe(e.addr("stv_fw_step_end"), probe(1))
    marks = []
    emu.step_start_observers.append(marks.append)
    emu.step_end_observers.append(marks.append)
    for _ in emu.chunks():
        pass
    got = [(m.kind, m.now, m.instructions, m.exception_instructions, m.cyccnt, m.ram, emu.tick_index(m)) for m in marks]
    assert len(got) > 2 * 300 and got == probed
    assert marks[-1].now / C.CPU_HZ == pytest.approx(5.0, abs=0.01)
    with pytest.raises(ValueError, match="not in the RAM ranges"):
        marks[0].ram_read(e.addr("ahrs") + 4, 16)


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_closing_the_source_while_its_board_runs_ahead_keeps_every_byte_it_made(reference_elf):
    from steval_link.live.emulated import EmulatedSource

    options = EmulationOptions(elf=reference_elf, scenario="hand-tilts", duration_s=8.0, seed=2)
    alone = b"".join(data for data, _ in Emulation(options).chunks())
    source = EmulatedSource(options)
    source.open()
    recorded: list = []
    rounds = source.chunks(recorded.append, None)
    handed = list(next(rounds)) + list(next(rounds))  # two rounds, while the board's thread runs ahead
    source.close()
    handed += [c for batch in rounds for c in batch]  # the session reads what close() took from the board
    data = b"".join(c.data for c in recorded if c.kind == "D")
    assert 0 < len(data) < len(alone) and alone.startswith(data)
    assert [c for c in recorded if c.kind in "DH"] == handed
    assert source.status.report is not None and source.status.report.usart_bytes == len(data)


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_a_stop_ends_the_run_at_its_slice_with_or_without_output(reference_elf):
    import threading

    emu = Emulation(EmulationOptions(elf=reference_elf, scenario="hand-tilts", duration_s=30.0, seed=1))
    stop = threading.Event()
    emu.step_end_observers.append(lambda mark: stop.set() if emu.n_steps == 200 else None)
    for _ in emu.chunks(stop=stop):
        pass
    t_s = emu.board.now / C.CPU_HZ
    assert emu.n_steps >= 200 and t_s < 2.985 + 200 / 161.5 + 0.1  # the slice of step 200, not the 30 s


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_a_script_reaches_the_rx_line_at_its_times_however_late_the_session_sends_it(reference_elf):
    import time

    from steval_link.link.commands import parse_command
    from steval_link.live.emulated import EmulatedSource

    options = EmulationOptions(elf=reference_elf, scenario="hand-tilts", duration_s=4.0, seed=2)
    script = [(1.5, parse_command("status")), (2.5, parse_command("set ki 1.0"))]
    source = EmulatedSource(options, commands=script)
    source.open()  # the board starts here, and would pass 1.5 s long before the session sends the script
    time.sleep(1.0)
    recorded: list = []
    rounds = source.chunks(recorded.append, None)
    for i, (t_s, command) in enumerate(script):
        source.write(command.encode(40 + i), at_s=t_s)
    for _batch in rounds:
        pass
    source.close()
    assert [(c.t_s, c.data) for c in recorded if c.kind == "H"] == [
        (t, c.encode(40 + i)) for i, (t, c) in enumerate(script)
    ]
    assert source.status.report.emulated_s == pytest.approx(4.0)
