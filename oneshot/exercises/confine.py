"""Confining the process that runs a student's code, from inside it, before the code loads (Linux).

    limit            memory (RLIMIT_AS), CPU seconds (RLIMIT_CPU), processes and threads (RLIMIT_NPROC),
                     file size (RLIMIT_FSIZE), no core files
    landlock         files: read only where Python, its libraries and the system live (not the oneshot
                     package's source, not the other submissions), write only in the working copy;
                     no TCP; no signals to processes outside (Landlock, Linux >= 5.13; TCP >= 6.7,
                     signals >= 6.12; less on older kernels, nothing where it is off)
    drop_privileges  run as `nobody` when the grader runs as root (root ignores RLIMIT_NPROC), with no
                     capabilities (under Landlock, owning root's files, so Python under /root imports)
    become_subreaper, kill_descendants   no process outlives the grading of its submission: a
                     subreaper inherits whatever a submission forks, even in a session of its own, and
                     kills it all at the end (each process also ends with its parent: `host.die_with_parent`)

Each is a no-op (returning False or 0) where the system does not offer it; `landlock_abi` says which
Landlock version the kernel has, so the grader can warn about what is missing.
"""
import ctypes
import os
import resource
import signal
import struct

NOBODY = 65534
_PR_SET_NO_NEW_PRIVS, _PR_SET_CHILD_SUBREAPER = 38, 36
_PR_SET_KEEPCAPS, _PR_CAPBSET_DROP, _CAP_SETUID = 8, 24, 7
_CREATE_RULESET, _ADD_RULE, _RESTRICT_SELF = 444, 445, 446        # the same on every Linux architecture
_EXECUTE, _WRITE_FILE, _READ_FILE, _READ_DIR, _REFER, _TRUNCATE = 1, 2, 4, 8, 1 << 13, 1 << 14
_READ = _EXECUTE | _READ_FILE | _READ_DIR


def _libc():
    libc = ctypes.CDLL(None, use_errno=True)
    libc.syscall.restype = ctypes.c_long
    return libc


def landlock_abi():
    """The kernel's Landlock ABI version (1-7 so far), or 0 where Landlock is missing or disabled."""
    try:
        return max(0, _libc().syscall(_CREATE_RULESET, None, ctypes.c_size_t(0), ctypes.c_uint32(1)))
    except (OSError, AttributeError):
        return 0


def _lower(which, soft, hard):
    """setrlimit(which, (soft, hard)), each no higher than the hard limit this process already has."""
    now = resource.getrlimit(which)[1]
    if now != resource.RLIM_INFINITY:
        soft, hard = min(soft, now), min(hard, now)
    resource.setrlimit(which, (soft, hard))


def limit(memory_bytes, cpu_seconds, processes, file_bytes=64 << 20, uid=None):
    """Set this process's limits: `memory_bytes` of address space beyond what it maps now, `cpu_seconds`
    of CPU time, `processes` more processes or threads than user `uid` (default: ours) has now, files
    of at most `file_bytes` (a bigger write fails with OSError, instead of SIGXFSZ killing the process).
    A limit the grader itself runs under (`ulimit`) is kept where it is lower: a process may not raise
    its hard limit, and asking to (`--memory 9000` under `ulimit -v 6000000`) failed every submission."""
    with open("/proc/self/status") as f:
        mapped = next(int(line.split()[1]) * 1024 for line in f if line.startswith("VmSize:"))
    cpu = max(1, int(cpu_seconds + 0.999))
    _lower(resource.RLIMIT_AS, mapped + memory_bytes, mapped + memory_bytes)
    _lower(resource.RLIMIT_CPU, cpu, cpu + 1)
    processes = tasks_of(os.getuid() if uid is None else uid) + processes
    _lower(resource.RLIMIT_NPROC, processes, processes)
    _lower(resource.RLIMIT_FSIZE, file_bytes, file_bytes)
    _lower(resource.RLIMIT_CORE, 0, 0)
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)


def tasks_of(uid):
    """The processes and threads user `uid` runs now (what RLIMIT_NPROC counts)."""
    count = 0
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            if os.stat(f"/proc/{pid}").st_uid == uid:
                count += len(os.listdir(f"/proc/{pid}/task"))
        except OSError:
            continue                                 # it ended while we looked
    return count


def _rules(root, hidden):
    """(path, is_folder) for every path to allow under `root` that holds none of `hidden` (real paths)."""
    root = os.path.realpath(root)
    if not os.path.exists(root) or any(root == h or root.startswith(h + os.sep) for h in hidden):
        return []
    if not any(h.startswith(root.rstrip(os.sep) + os.sep) for h in hidden):
        return [(root, os.path.isdir(root))]
    rules = []
    try:
        names = os.listdir(root)
    except OSError:
        return []
    for name in names:                               # the hidden path is below: allow its siblings only
        rules += _rules(os.path.join(root, name), hidden)
    return rules


def landlock(writable, readable, hidden=(), files=("/dev/null",)):
    """Restrict this process and its future children: read and execute beneath `readable` except beneath
    `hidden`, read and write beneath `writable` and the `files`; no TCP bind or connect; no signals or
    abstract Unix sockets to processes outside. Irreversible. Returns the ABI used (0: not available)."""
    abi = landlock_abi()
    if abi < 1:
        return 0
    handled = (1 << 13) - 1 | (_REFER if abi >= 2 else 0) | (_TRUNCATE if abi >= 3 else 0)
    attr = struct.pack("=QQQ", handled, 3 if abi >= 4 else 0, 3 if abi >= 6 else 0)
    attr = attr[:24 if abi >= 6 else 16 if abi >= 4 else 8]
    libc = _libc()
    ruleset = libc.syscall(_CREATE_RULESET, ctypes.create_string_buffer(attr), ctypes.c_size_t(len(attr)),
                           ctypes.c_uint32(0))
    if ruleset < 0:
        return 0
    hidden = [os.path.realpath(h) for h in hidden]
    rules = [(path, folder, _READ) for root in readable for path, folder in _rules(root, hidden)]
    rules += [(os.path.realpath(w), True, handled) for w in writable]
    rules += [(f, False, _READ_FILE | _WRITE_FILE | (_TRUNCATE & handled)) for f in files if os.path.exists(f)]
    for path, folder, access in rules:
        access &= handled if folder else (_EXECUTE | _READ_FILE | _WRITE_FILE | _TRUNCATE) & handled
        try:
            fd = os.open(path, os.O_PATH | os.O_CLOEXEC)
        except OSError:
            continue
        try:
            rule = ctypes.create_string_buffer(struct.pack("=Qi", access, fd))
            libc.syscall(_ADD_RULE, ctypes.c_int(ruleset), ctypes.c_int(1), rule, ctypes.c_uint32(0))
        finally:
            os.close(fd)
    libc.prctl(_PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0)
    done = libc.syscall(_RESTRICT_SELF, ctypes.c_int(ruleset), ctypes.c_uint32(0))
    os.close(ruleset)
    return abi if done == 0 else 0


def drop_privileges(uid=NOBODY, keep_files=False):
    """If this process is root, become user `uid` (real, effective and saved; no groups, no capabilities,
    none to regain on exec): RLIMIT_NPROC counts `uid`'s processes (root is exempt from it), signals
    and ptrace are `uid`'s. With `keep_files` (when Landlock confines the files), keep root's FILE
    identity (fsuid 0), as the owner only (no capability overrides a permission), so Python installed
    under /root (mode 700) still imports. Returns whether it dropped root."""
    if os.geteuid() != 0:
        return False
    libc = _libc()
    for cap in range(64):                            # no capability can come back, even by exec
        libc.prctl(_PR_CAPBSET_DROP, cap, 0, 0, 0)
    libc.prctl(_PR_SET_KEEPCAPS, 1, 0, 0, 0)
    os.setgroups([])
    os.setresgid(uid, uid, uid)
    os.setresuid(uid, uid, uid)                      # fsuid follows: back to 0 with CAP_SETUID, then no caps
    if keep_files:
        _capset(1 << _CAP_SETUID)
        libc.setfsuid(0)
    _capset(0)
    libc.prctl(_PR_SET_KEEPCAPS, 0, 0, 0, 0)
    return os.getuid() == uid


def _capset(mask):
    """Set this process's effective and permitted capabilities to `mask` (no inheritable ones)."""
    header = ctypes.create_string_buffer(struct.pack("=Ii", 0x20080522, 0))     # _LINUX_CAPABILITY_VERSION_3
    data = ctypes.create_string_buffer(struct.pack("=6I", mask & 0xFFFFFFFF, mask & 0xFFFFFFFF, 0,
                                                   mask >> 32, mask >> 32, 0))
    if _libc().capset(header, data) != 0:
        raise OSError(ctypes.get_errno(), "capset failed")


def become_subreaper():
    """Adopt every orphan among our descendants (prctl PR_SET_CHILD_SUBREAPER), so `kill_descendants`
    finds a process that double-forked into a session of its own."""
    return _libc().prctl(_PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) == 0


def _children():
    me, found = os.getpid(), []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{pid}/stat", "rb") as f:
                fields = f.read().rsplit(b")", 1)[1].split()       # after "pid (comm)": state, ppid, ...
        except (OSError, IndexError):
            continue
        if len(fields) > 1 and int(fields[1]) == me:
            found.append(int(pid))
    return found


def kill_descendants(rounds=1000):
    """SIGKILL and reap every child of this process, round after round: a subreaper inherits the children
    of those it kills, until none is left (or `rounds` rounds have passed)."""
    for _ in range(rounds):
        children = _children()
        if not children:
            return
        for pid in children:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        for pid in children:
            try:
                os.waitpid(pid, 0)
            except ChildProcessError:
                pass
