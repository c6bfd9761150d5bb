"""``ns2 flash``: ``build/app/cf2.bin`` to one robot or to every enabled robot of a swarm
file, through cflib's bootloader (``cflib.bootloader.Bootloader.flash_full``: warm
boot over the radio into the bootloader, the STM32 firmware written, reset to the
firmware), one robot after the other; a robot that fails does not stop the others
and is reported with the reason."""
from __future__ import annotations

import contextlib
import sys
from pathlib import Path

from ns2codegen.errors import Ns2Error

MIN_IMAGE = 64 * 1024    # a cf2.bin is some 300 KB; less is not a firmware image


class FlashError(Ns2Error, RuntimeError):
    """The image cannot be flashed, or some robots failed."""


def check_image(path) -> Path:
    path = Path(path)
    if not path.is_file():
        raise FlashError(f"{path}: no firmware image (make app writes build/app/cf2.bin)")
    if path.suffix != ".bin" or path.stat().st_size < MIN_IMAGE:
        raise FlashError(f"{path}: not a cf2 firmware image (.bin of at least {MIN_IMAGE // 1024} KB)")
    return path


def _bootloader(uri):
    from cflib.bootloader import Bootloader   # [fly] extra

    return Bootloader(uri)


def flash(image, robots: dict[str, str], progress=None, bootloader=None) -> dict[str, str | None]:
    """Flash ``image`` to each robot (name -> uri) in turn; returns name -> None (done)
    or the reason it failed.  ``progress(name, message, percent)``."""
    import cflib.crtp
    from cflib.bootloader import Target

    image = check_image(image)
    if not cflib.crtp.CLASSES:
        cflib.crtp.init_drivers()
    out = {}
    for name, uri in robots.items():
        bl = None
        said = []   # cflib's progress messages: its reason when it raises a bare Exception

        def report(msg, pct, n=name, said=said):
            said.append(str(msg))
            if progress:
                progress(n, msg, pct)

        try:
            bl = (bootloader or _bootloader)(uri)
            with contextlib.redirect_stdout(sys.stderr):   # cflib prints; stdout is the command's (--json)
                bl.flash_full(cf=None, filename=str(image), warm=True,
                              targets=[Target("cf2", "stm32", "fw", [], [])], progress_cb=report)
            out[name] = None
        except Exception as e:  # noqa: BLE001  cflib raises bare Exception; one robot must not stop the rest
            if getattr(getattr(bl, "_cload", None), "link", True) is None:   # cflib found no link driver
                out[name] = f"no radio link to {uri} (Crazyradio plugged in? robot on? address right?)"
            else:
                out[name] = (" ".join(str(e).split()) or next((m for m in reversed(said) if m.startswith("Error")),
                                                               type(e).__name__))
        finally:
            if bl is not None:
                try:
                    bl.close()
                except Exception:  # noqa: BLE001
                    pass
    return out
