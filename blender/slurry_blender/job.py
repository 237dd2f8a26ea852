"""A scene run in a worker thread, advanced from Blender's main thread by plain calls.

The Run operator's modal timer calls `RunJob.tick()` and shows what it returns (the status bar's
text, the progress indicator); `RunJob.cancel()` is its Esc. Nothing here touches Blender's
interface, so a script, or a test without an event loop, drives a run the same way:

    job = RunJob(slurry, scene, directory, frames=4, threads=2)
    while job.tick().state == "running":
        job.wait(0.1)

`slurry.run_scene` releases the GIL while it simulates and calls back after every frame (frame 0
included); the callback only queues the frame, and `tick` takes what was queued since the last
call. A cancelled run stops after the frame it is computing, which it writes with a checkpoint,
so `RunJob(..., resume=True)` continues it.
"""
import os
import queue
import threading
from collections import namedtuple

Tick = namedtuple("Tick", "state frame frames new_frames text summary error")
Tick.__doc__ = """What a tick found. state: "running", "done" (every frame written), "stopped"
(cancelled; the frames up to `frame` are written) or "error" (`error` holds the exception);
frame: the newest frame written (-1 before frame 0); frames: the last frame of the run;
new_frames: the frames written since the previous tick, in order; text: a status line;
summary: run_scene's summary once the run has ended."""


class RunJob:
    def __init__(self, slurry, scene, directory, frames=None, threads=0, resume=False):
        """Starts `slurry.run_scene(scene)` into `directory` in a daemon thread. frames: the last
        frame (None: the scene's output.frames)."""
        self.scene = scene
        self.directory = directory
        self.frames = frames or scene.frames
        self.token = slurry.StopToken()
        self.frame = -1
        self.seconds = 0.0
        self._events = queue.SimpleQueue()
        self._result = None
        kwargs = dict(directory=directory, frames=frames or None, threads=threads, resume=resume,
                      stop=self.token, on_frame=self.frame_written)

        def work():
            try:
                self._result = ("done", slurry.run_scene(scene, **kwargs))
            except BaseException as e:  # handed to the main thread by tick()
                self._result = ("error", e)

        self._thread = threading.Thread(target=work, name="slurry run", daemon=True)
        self._thread.start()

    def frame_written(self, report):
        """Called in the worker after every frame with run_scene's frame dict: queues the frame
        for tick()."""
        self._events.put((report["frame"], report["seconds"]))

    def cancel(self):
        """Asks the worker to stop after the frame it is computing."""
        self.token.request()

    @property
    def cancelled(self):
        return self.token.requested

    def wait(self, timeout=None):
        """Blocks until the worker ends or `timeout` seconds pass (between ticks of a script)."""
        self._thread.join(timeout)

    def _take_frames(self):
        new = []
        while True:
            try:
                frame, seconds = self._events.get_nowait()
            except queue.Empty:
                return new
            new.append(frame)
            self.frame, self.seconds = frame, seconds

    def tick(self):
        """Takes the frames written since the last call; the run's end once the worker is done."""
        # Asked before the queue is read: a worker that had ended by then had queued every frame.
        alive = self._thread.is_alive()
        new = self._take_frames()
        name = os.path.basename(self.scene.source)
        if alive:
            if self.cancelled:
                text = f"Slurry: stopping {name} after the current frame ({self.frame}/{self.frames} written)"
            else:
                text = f"Slurry: {name} frame {self.frame}/{self.frames} ({self.seconds:.1f} s a frame), Esc cancels"
            return Tick("running", self.frame, self.frames, new, text, None, None)
        kind, value = self._result
        if kind == "error":
            return Tick("error", self.frame, self.frames, new, f"Slurry: {value}", None, value)
        if value["stopped"]:
            text = (f"Slurry: cancelled after frame {value['frames_written'] - 1} of {self.frames} "
                    f"(tick Resume to continue from its checkpoint)")
            return Tick("stopped", self.frame, self.frames, new, text, value, None)
        text = (f"Slurry: frames 0-{value['frames_written'] - 1} in {self.directory} "
                f"({value['wall_seconds']:.1f} s)")
        return Tick("done", self.frame, self.frames, new, text, value, None)
