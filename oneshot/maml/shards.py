"""One meta-iteration on several processes, each on its own frames of every demo (data parallelism).

autograd's Python keeps one process at about one core, so the meta-gradient of Section II is shared
by `shards` processes (2 on the project's 2-core machine). They split the demos' FRAMES, not the
meta-batch's tasks: 5 tasks do not halve, and with 3 tasks here and 2 there one core idled for a
quarter of every iteration. With frames, process r computes all B tasks on its block of the T frames.

Eq. (2) is a sum over frames and the network treats frames independently, so everything splits except
eq. (1)'s inner gradient, which every task's adapted parameters need whole: each process computes the
gradient of its frames' loss and `allreduce` adds up every process's part, in the same order in every
process, so all of them hold bit-identical adapted parameters. `allreduce` is an autograd primitive
whose VJP is `allreduce` again (each process uses the sum, so the cotangent of every part is the sum of
theirs), which keeps the meta-gradient second order. Each process ends with the gradient of its frames'
share of the meta-objective; one more exchange adds them up: the meta-gradient.

The processes meet at every `allreduce` (twice per inner gradient: once forward, once backward), through
shared memory and one-byte tokens on pipes; they run the same code on the same shapes, so they meet in
the same order. The worker processes are forked once and then read their parameters and frames from
shared memory each iteration (nothing is pickled but the settings). Results depend on `shards`, never
on the number of cores: `shards` processes run even on one core. What splitting frames rather than
tasks buys is measured in docs/results.md ("Speed").
"""
import mmap
import multiprocessing
import os
import select
import signal
import traceback

import numpy as np
from autograd.extend import defvjp, primitive

from oneshot.maml import batched
from oneshot.tools.host import blas_threads, die_with_parent

TIMEOUT = 600.0   # seconds a process waits for the others at one exchange before giving up


class ShardError(RuntimeError):
    """A shard process failed, died or went silent in the middle of a meta-gradient."""


# ----------------------------------------------------------------------------------------------------
# Sums across processes
# ----------------------------------------------------------------------------------------------------


class Exchange:
    """Sums arrays across `ranks` processes forked after it was made (each sets its `rank`).

    Shared memory holds two slots per rank (alternate exchanges use alternate slots); a one-byte token
    on a pipe from every rank to every other says "my slot for this exchange is written". Before a rank
    reuses a slot (two exchanges later) it has had every other rank's token of the exchange in between,
    which they send only after reading that slot: no lock is needed.
    """

    def __init__(self, ranks, slot_bytes):
        self.ranks, self.slot_bytes = ranks, int(slot_bytes)
        self.memory = mmap.mmap(-1, ranks * 2 * self.slot_bytes)      # anonymous, shared with children
        self.pipes = {(i, j): os.pipe() for i in range(ranks) for j in range(ranks) if i != j}
        self.rank, self.count, self.broken, self.watch = ranks - 1, 0, False, []

    def _slot(self, rank, parity, dtype, size):
        return np.frombuffer(self.memory, dtype, size, (2 * rank + parity) * self.slot_bytes)

    def sum(self, x):
        """x summed over all ranks, rank 0 first: the same bits in every process. x: an array whose
        shape and dtype every rank shares, of at most `slot_bytes` bytes."""
        if self.broken:
            raise ShardError("the shard processes are out of step after an earlier error")
        x = np.ascontiguousarray(x)
        if x.nbytes > self.slot_bytes:
            raise ValueError(f"an exchanged array of {x.nbytes} bytes does not fit the {self.slot_bytes}-byte slots")
        parity, self.count = self.count % 2, self.count + 1
        self._slot(self.rank, parity, x.dtype, x.size)[:] = x.ravel()
        peers = [j for j in range(self.ranks) if j != self.rank]
        for j in peers:
            os.write(self.pipes[(self.rank, j)][1], b".")
        for j in peers:
            token = self._receive(self.pipes[(j, self.rank)][0])
            if token != b".":
                self.broken = True
                raise ShardError(f"shard process {j} " + {b"!": "failed", b"x": "died"}.get(
                    token, f"did not answer within {TIMEOUT:.0f} s") + " during a meta-gradient")
        parts = [x.ravel() if j == self.rank else self._slot(j, parity, x.dtype, x.size) for j in range(self.ranks)]
        total = parts[0] + parts[1]
        for p in parts[2:]:
            total += p
        return total.reshape(x.shape)

    def _receive(self, fd):
        """One byte from the pipe fd, waited for while watching `watch` (the workers' sentinels: a
        worker that dies is reported instead of waited for)."""
        ready = select.select([fd, *self.watch], [], [], TIMEOUT)[0]
        return os.read(fd, 1) if fd in ready else b"x" if ready else b""

    def close(self):
        """Close the pipes (the shared memory goes with the last reference to it)."""
        for reading, writing in self.pipes.values():
            os.close(reading)
            os.close(writing)
        self.pipes, self.broken = {}, True

    def abort(self):
        """Tell every other rank that this one failed (they raise `ShardError` instead of waiting)."""
        self.broken = True
        for j in range(self.ranks):
            if j != self.rank:
                os.write(self.pipes[(self.rank, j)][1], b"!")


@primitive
def allreduce(x, exchange):
    """x summed over the processes of `exchange`. Linear, and its VJP is itself: every order works."""
    return exchange.sum(x)


defvjp(allreduce, lambda ans, x, exchange: lambda g: allreduce(g, exchange))


# ----------------------------------------------------------------------------------------------------
# One process's part of the meta-gradient
# ----------------------------------------------------------------------------------------------------


def split_frames(demos, shards):
    """A batched demo (tuple of (B, T, ...) arrays) -> `shards` demos of contiguous blocks of frames."""
    T = demos[0].shape[1]
    if not 1 <= shards <= T:
        raise ValueError(f"cannot split demos of {T} frames into {shards} shards; use 1 <= shards <= {T}")
    bounds = np.linspace(0, T, shards + 1).astype(int)
    return [tuple(a[:, i:j] for a in demos) for i, j in zip(bounds[:-1], bounds[1:])]


def part(params, adapt, evaluate, settings, exchange=None):
    """This process's part: (value, grads) of its frames' share of the meta-objective, summed over the
    processes of `exchange` when there is one (then every process returns the whole meta-gradient).

    settings: (loss_tasks, inner) as in `batched.meta_gradient_batched`: the summed loss (a module-level
    function: the workers receive it pickled) and the `inner.InnerLoop`.
    """
    loss_tasks, inner = settings
    if exchange is None:
        return batched.meta_gradient_batched(params, adapt, evaluate, loss_tasks, inner)
    value, grads = batched.meta_gradient_batched(params, adapt, evaluate, loss_tasks, inner,
                                                 reduce=lambda g: allreduce(g, exchange))
    flat = [grads[k].ravel() for k in params]
    flat = exchange.sum(np.concatenate(flat + [np.ravel(value).astype(flat[0].dtype)]))   # (n_params + 1,)
    offsets = np.cumsum([0] + [v.size for v in params.values()])
    grads = {k: flat[i:j].reshape(np.shape(v)) for (k, v), i, j in zip(params.items(), offsets[:-1], offsets[1:])}
    return flat[-1], grads


# ----------------------------------------------------------------------------------------------------
# The processes
# ----------------------------------------------------------------------------------------------------


class Pool:
    """`shards - 1` worker processes that compute the meta-gradient with this one (`meta_gradient`).

    The workers are forked at the first call, when the shapes of the parameters and demos are known
    (and again if they change, or after an error). Use as a context manager, or call `close`. Every
    process, this one included, keeps to one BLAS thread: two processes with two spinning BLAS threads
    each on two cores were 5x slower than one process.
    """

    def __init__(self, shards):
        if shards < 2:
            raise ValueError(f"a Pool needs shards >= 2 (shards = 1 needs no pool); got {shards}")
        self.shards, self.workers, self.layout, self.exchange = shards, [], None, None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        """Stop the workers (they hold no state worth keeping)."""
        for process, conn in self.workers:
            process.kill()
            process.join()
            conn.close()
        if self.exchange is not None:
            self.exchange.close()
        self.workers, self.layout = [], None

    def meta_gradient(self, params, adapt, evaluate, settings):
        """(value, grads) of the meta-objective over all frames, this process computing the last block
        of frames and each worker one of the others. settings: as in `part`."""
        blocks = list(zip(split_frames(adapt, self.shards), split_frames(evaluate, self.shards)))
        jobs = [[*params.values(), *a, *e] for a, e in blocks[:-1]]         # each worker's arrays
        layout = (tuple(params), len(adapt), [[(x.shape, x.dtype.str) for x in job] for job in jobs])
        if layout != self.layout or self.exchange.broken:
            self._start(layout, sum(x.nbytes for x in params.values()) * len(adapt[0]),
                        sum(x.nbytes for x in params.values()))
        for mailbox, job in zip(self.mailboxes, jobs):    # parameters and frames into shared memory
            for view, x in zip(mailbox, job):
                view[...] = x
        for rank, (process, conn) in enumerate(self.workers):
            try:
                conn.send(settings)
            except OSError:
                self.exchange.broken = True                  # the next call starts new workers
                raise ShardError(f"shard process {rank} died (exit code {process.exitcode})") from None
        try:
            return part(params, *blocks[-1], settings, self.exchange)
        except ShardError as error:
            raise ShardError("\n".join([str(error), *self._messages()])) from None
        except BaseException:
            if not self.exchange.broken:
                self.exchange.abort()
            raise

    def _messages(self):
        """The tracebacks of workers that failed (a dead worker has none)."""
        messages = []
        for _, conn in self.workers:
            try:
                messages += [conn.recv()] if conn.poll(1.0) else []
            except (EOFError, OSError):
                pass
        return messages

    def _start(self, layout, inner_bytes, param_bytes):
        """Fork the workers, each with a mailbox (shared memory) laid out for its arrays."""
        self.close()
        keys, n_demo, jobs = layout
        self.mailboxes = []
        for job in jobs:
            sizes = [int(np.prod(shape)) * np.dtype(dtype).itemsize for shape, dtype in job]
            memory, offsets = mmap.mmap(-1, max(1, sum(sizes))), np.cumsum([0] + sizes)
            self.mailboxes.append([np.frombuffer(memory, dtype, int(np.prod(shape)), int(o)).reshape(shape)
                                   for (shape, dtype), o in zip(job, offsets)])
        # slots for the largest exchange: an inner gradient (every task's copy of every adapted
        # parameter, packed into one vector: `batched._reduced`) or the final meta-gradient of every
        # parameter and the loss
        self.exchange = Exchange(self.shards, max(inner_bytes, param_bytes + 8))
        blas_threads(1)
        context = multiprocessing.get_context("fork")
        for rank, mailbox in enumerate(self.mailboxes):
            params = dict(zip(keys, mailbox))
            demos = mailbox[len(keys):]
            here, there = context.Pipe()
            process = context.Process(target=_serve, daemon=True, args=(
                self.exchange, rank, params, tuple(demos[:n_demo]), tuple(demos[n_demo:]), there, os.getpid()))
            process.start()
            there.close()
            self.workers.append((process, here))
        self.exchange.watch = [process.sentinel for process, _ in self.workers]
        self.layout = layout


def _serve(exchange, rank, params, adapt, evaluate, conn, parent):
    """A worker's loop: wait for the go (the settings), compute its part from the mailbox, repeat.
    It dies with the training process (`parent`), however that ends."""
    die_with_parent(parent)
    signal.signal(signal.SIGINT, signal.SIG_IGN)      # Ctrl-C is for the training process, which stops us
    signal.signal(signal.SIGTERM, signal.SIG_DFL)     # not the training process's handler (train.main)
    blas_threads(1)
    exchange.rank = rank
    while True:
        try:
            settings = conn.recv()
        except EOFError:
            return
        try:
            part(params, adapt, evaluate, settings, exchange)
        except BaseException:
            if not exchange.broken:
                exchange.abort()
            conn.send(f"shard process {rank}: {traceback.format_exc()}")
            return


def make_pool(shards):
    """A `Pool` for `shards` processes, or None when shards == 1 (one process does everything)."""
    if isinstance(shards, bool) or not isinstance(shards, int) or shards < 1:
        raise ValueError(f"shards is the number of processes sharing each meta-gradient, an int >= 1; "
                         f"got {shards!r}")
    return Pool(shards) if shards > 1 else None


def meta_gradient(params, adapt, evaluate, settings, shards=1, pool=None):
    """The meta-objective (mean over tasks) and its gradient, each of `shards` processes on its block
    of frames.

    params: dict of arrays. adapt, evaluate: batched demos (tuples of (B, T, ...) arrays).
    settings: (loss_tasks, inner) as in `part`.
    pool: `make_pool(shards)`, needed when shards > 1.
    Returns (value, grads) as `batched.meta_gradient_batched`; the numbers depend on `shards` only.
    """
    if shards == 1:
        return part(params, adapt, evaluate, settings)
    if pool is None or pool.shards != shards:
        raise ValueError(f"shards = {shards} needs a pool of as many processes: shards.make_pool({shards})")
    return pool.meta_gradient(params, adapt, evaluate, settings)
