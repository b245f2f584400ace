"""The serial bridge's side of the closed loop: the gains sent as acknowledged coefficients, the reference, the
ACKs and the control telemetry (a mixin of :class:`aeropend_ros.serial_bridge_node.SerialBridgeNode`, which
declares the parameters and owns the link; the protocol is in :mod:`aeropend_core.rig.protocol`).
"""
from __future__ import annotations


from aeropend_core.rig import protocol as P
from aeropend_core.rig.control_link import GainsUpload
from aeropend_ros.control_parameters import checked_reference


class BridgeControl:
    """Closed-loop methods of the bridge node; they use the node's ``_write``, logger, gains and calibration."""

    def _calibration_command(self) -> bytes:
        return P.encode_angle_calibration(self.calibration.angle_zero, self.calibration.angle_scale)

    def _start_upload(self) -> None:
        """Send the gains as 14 coefficients; the reader thread checks the ACKs (_on_ack)."""
        upload = GainsUpload(self.gains, self.sample_period)
        with self._control_lock:
            if not self._write(upload.start()):
                self._upload, self.gains_state = None, 'not sent'
                return
            self._upload, self.gains_state = upload, 'sending'

    def _close_loop(self) -> None:
        """Reference (if any) and SET_CONTROL_MODE 1, once the gains are acknowledged (else when they are)."""
        with self._control_lock:
            if self.gains_state != 'acknowledged':
                return
            data = b''
            if self.reference is not None:
                data += P.encode_reference(*self.reference)
            self._write(data + P.encode_control_mode(P.MODE_CLOSED_LOOP))

    def _configure_controller(self) -> None:
        """After the device (re)starts: calibration (open loop only takes it), gains; closed loop follows."""
        self._device_closed = False
        self._write(self._calibration_command())   # (refused, harmlessly, by a device still in closed loop)
        self._start_upload()

    def _on_ack(self, ack: P.AckFrame) -> None:
        """An ACK (reader thread): the gain upload's, the mode's or a reference's."""
        logger = self.get_logger()
        if not ack.ok:
            self.control_stats['acks_refused'] += 1
        if ack.command == P.SET_CONTROL_COEFFICIENT:
            with self._control_lock:
                upload = self._upload
                if upload is None:
                    return
                resend = upload.accept(ack)
                if resend:
                    self._write(resend)
                if upload.error is not None:
                    self.gains_state = f'refused: {upload.error}'
                    self._upload = None
                    logger.error(f'the device refused the controller gains: {upload.error}')
                    return
                if not upload.done:
                    return
                self._upload = None
                self.gains_state = 'acknowledged'
            logger.info('controller gains acknowledged by the device')
            if self.closed_loop and not self._device_closed:
                self._close_loop()
        elif ack.command == P.SET_CONTROL_MODE:
            if ack.ok:
                self._device_closed = ack.value == P.MODE_CLOSED_LOOP
                if self._device_closed:
                    self._trip_said = False
                    logger.info('the device runs the closed loop')
            else:
                logger.error(f'the device refused SET_CONTROL_MODE: {ack.describe()}')
        elif ack.command == P.SET_REFERENCE and not ack.ok:
            logger.warning(f'the device refused the reference: {ack.describe()}', throttle_duration_sec=2.0)
        elif ack.command == P.SET_ANGLE_CALIBRATION and not ack.ok and ack.result != P.ACK_REFUSED:
            logger.error(f'the device refused the angle calibration: {ack.describe()}')

    def _on_reference(self, msg) -> None:
        """A reference (std_msgs/Float64MultiArray: [reference_rad] or [reference_rad, feedforward_duty])."""
        from aeropend_core.control.feedforward import static_duty
        checked = checked_reference(msg.data, self.gains, static_duty)
        if isinstance(checked, str):
            self.get_logger().warning(checked, throttle_duration_sec=2.0)
            return
        reference, feedforward = checked
        self.reference = (reference, feedforward)
        self._write(P.encode_reference(reference, feedforward))

    def _publish_control(self, frame: P.ControlSampleFrame, stamp) -> None:
        control = self._control_message
        control.header.stamp = stamp
        control.position = [frame.reference, frame.feedforward, frame.duty, frame.unsaturated, frame.integral,
                            1.0 if frame.tripped else 0.0, float(frame.sequence)]
        self.control_publisher.publish(control)
        self.control_stats['control_published'] += 1

