"""The emulated USART1's receiver as an STM32F401's: bytes injected at emulated times arrive 10 bit times apart at
the BRR's baud rate; RXNE, the RXNE interrupt, DR reads, overrun (ORE, cleared by SR then DR), a disabled
receiver. The Python model and the C core's, the same assertions. (The real firmware's use of it:
tests/test_twoway_firmware.py.)"""

from __future__ import annotations

import pytest
from support.tiny_elf import tiny_elf

from steval_link.emulation.board import IRQ_BASE, IRQ_USART1, Nvic, Usart

SR, DR, BRR, CR1 = 0x00, 0x04, 0x08, 0x0C
UE, RE, TE, RXNEIE = 1 << 13, 1 << 2, 1 << 3, 1 << 5
RXNE, ORE = 1 << 5, 1 << 3


class _Board:
    """What a peripheral sees of the board: the clock, the NVIC, the event scheduler."""

    def __init__(self) -> None:
        self.now = 0
        self.nvic = Nvic()
        self.rescheduled = 0

    def reschedule(self) -> None:
        self.rescheduled += 1

    def uart_out(self, byte: int, t: int) -> None:
        pass


@pytest.fixture(params=["python", "native"])
def model(request, tmp_path):
    """Builds (board, USART1) of the Python model or of the C core."""
    if request.param == "python":
        return lambda: (_Board(), None)
    pytest.importorskip("unicorn")
    from steval_link.emulation.board import NativeBoard, core_library

    if core_library() is None:
        pytest.skip("the C core is not built")
    path = tmp_path / "loop.elf"
    path.write_bytes(tiny_elf())

    def make():
        board = NativeBoard(path, None)
        board.rescheduled = 1  # (the C core reschedules itself)
        return board, board.usart1

    return make


@pytest.fixture
def _uart(model):
    def make(cr1=UE | RE | TE | RXNEIE):
        board, u = model()
        if u is None:
            u = Usart(board, 0x40011000, IRQ_USART1)
        u.write(BRR, 729)  # 115200 baud at 84 MHz: a bit every 729 cycles
        u.write(CR1, cr1)
        return board, u

    return make


def _pending(board) -> bool:
    return IRQ_USART1 + IRQ_BASE in board.nvic.pending


def test_bytes_arrive_at_the_baud_rate_and_raise_rxne(_uart):
    board, u = _uart()
    u.inject(b"AB", 1000)
    assert u.rx_done == 1000 + 7290 and board.rescheduled
    assert not u.read(SR) & RXNE
    board.now = u.rx_done
    u.rx_complete()
    assert u.read(SR) & RXNE and _pending(board)
    assert u.rx_done == 1000 + 2 * 7290  # back to back
    assert u.read(DR) == ord("A")
    assert not u.read(SR) & RXNE and not _pending(board)
    board.now = u.rx_done
    u.rx_complete()
    assert u.read(DR) == ord("B") and u.rx_done is None
    assert [b for b, _ in u.rx_log] == [ord("A"), ord("B")] and u.rx_received == 2


def test_later_injections_wait_for_the_line_and_keep_time_order(_uart):
    board, u = _uart()
    u.inject(b"x", 50_000)
    u.inject(b"y", 10_000)  # scheduled earlier, added later: goes first
    assert u.rx_done == 10_000 + 7290
    board.now = u.rx_done
    u.rx_complete()
    assert u.read(DR) == ord("y") and u.rx_done == 50_000 + 7290


def test_overrun_keeps_the_older_byte_and_sr_then_dr_clears_it(_uart):
    board, u = _uart(UE | RE)  # no interrupt: nobody reads in time
    u.inject(b"12", 0)
    for _ in range(2):
        board.now = u.rx_done
        u.rx_complete()
    assert u.rx_overruns == 1 and not _pending(board)
    sr = u.read(SR)
    assert sr & RXNE and sr & ORE
    assert u.read(DR) == ord("1")  # the receive register kept the first byte
    assert not u.read(SR) & (RXNE | ORE)


def test_overrun_raises_the_interrupt_with_rxneie(_uart):
    board, u = _uart()
    u.inject(b"12", 0)
    for _ in range(2):
        board.now = u.rx_done
        u.rx_complete()
    assert _pending(board)
    u.read(SR)
    u.read(DR)
    assert not _pending(board)


def test_a_disabled_receiver_loses_the_bytes(_uart):
    board, u = _uart(UE | TE)
    u.inject(b"z", 0)
    board.now = u.rx_done
    u.rx_complete()
    assert u.rx_lost == 1 and not u.read(SR) & RXNE
