/* The tty itself: claiming it for this process (flock, TIOCEXCL), the line settings
 * libmodbus cannot make, RTS.  Those settings are any baud rate (termios2 + BOTHER;
 * libmodbus silently turns rates outside its table into 9600), mark and space parity
 * (CMSPAR; libmodbus refuses them), low-latency mode, and the kernel's RS-485 direction
 * control, the RS-232 control lines and flow control.  <asm/termbits.h> clashes with
 * <termios.h>, hence this file of its own. */
#include <asm/ioctls.h>
#include <asm/termbits.h>
#include <errno.h>
#include <fcntl.h>
#include <linux/serial.h>
#include <stddef.h>
#include <stdint.h>
#include <sys/file.h>
#include <sys/ioctl.h>
#include <sys/prctl.h>
#include <unistd.h>

#include "internal.h"
#include "mbgw.h"

int mbgw_tty_lock(const char *path, int dtr_low, int rts_low)
{
    int fd = open(path, O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0)
        return -errno;
    if (flock(fd, LOCK_EX | LOCK_NB) < 0) {
        int err = errno == EWOULDBLOCK ? EBUSY : errno;
        close(fd);
        return -err;
    }
    int lines = (dtr_low ? TIOCM_DTR : 0) | (rts_low ? TIOCM_RTS : 0);
    /* best effort: a tty without modem lines (a pty) refuses, and has nothing to lower;
     * the settings applied later say so (mbgw_tty_modem_lines) */
    if (lines)
        (void)ioctl(fd, TIOCMBIC, &lines);
    return fd;
}

int mbgw_tty_claim(int fd)
{
    if (ioctl(fd, TIOCEXCL) < 0 && errno != ENOTTY)
        return -errno;
    return 0;
}

int mbgw_tty_release(int fd)
{
    if (ioctl(fd, TIOCNXCL) < 0 && errno != ENOTTY)
        return -errno;
    return 0;
}

/* --- settings --- */

uint32_t mbgw_tty_cflag(uint32_t cflag, int data_bits, char parity, int stop_bits)
{
    cflag &= ~(uint32_t)(CSIZE | PARENB | PARODD | CMSPAR | CSTOPB);
    cflag |= data_bits == 7 ? CS7 : CS8;
    switch (parity) {
    case 'e':
        cflag |= PARENB;
        break;
    case 'o':
        cflag |= PARENB | PARODD;
        break;
    case 'm': /* parity bit always 1 */
        cflag |= PARENB | CMSPAR | PARODD;
        break;
    case 's': /* parity bit always 0 */
        cflag |= PARENB | CMSPAR;
        break;
    default:
        break;
    }
    if (stop_bits == 2)
        cflag |= CSTOPB;
    return cflag;
}

int mbgw_tty_set_format(int fd, int data_bits, char parity, int stop_bits)
{
    struct termios2 tio;
    if (ioctl(fd, TCGETS2, &tio) < 0)
        return -errno;
    tio.c_cflag = mbgw_tty_cflag(tio.c_cflag, data_bits, parity, stop_bits);
    if (parity == 'm' || parity == 's')
        tio.c_iflag &= ~(uint32_t)INPCK; /* a device may answer in another parity */
    if (ioctl(fd, TCSETS2, &tio) < 0)
        return -errno;
    return 0;
}

int mbgw_tty_set_baud(int fd, uint32_t baud)
{
    struct termios2 tio;
    if (ioctl(fd, TCGETS2, &tio) < 0)
        return -errno;
    tio.c_cflag &= ~(uint32_t)CBAUD;
    tio.c_cflag |= BOTHER;
    tio.c_ispeed = tio.c_ospeed = baud;
    if (ioctl(fd, TCSETS2, &tio) < 0)
        return -errno;
    return 0;
}

int mbgw_tty_get(int fd, uint32_t *cflag, uint32_t *baud)
{
    struct termios2 tio;
    if (ioctl(fd, TCGETS2, &tio) < 0)
        return -errno;
    *cflag = tio.c_cflag;
    *baud = tio.c_ospeed;
    return 0;
}

int mbgw_tty_low_latency(int fd)
{
    struct serial_struct ss;
    if (ioctl(fd, TIOCGSERIAL, &ss) < 0)
        return -errno;
    ss.flags |= ASYNC_LOW_LATENCY;
    if (ioctl(fd, TIOCSSERIAL, &ss) < 0)
        return -errno;
    return 0;
}

int mbgw_tty_rs485(int fd, int before_ms, int after_ms, int rx_during_tx)
{
    struct serial_rs485 rs;
    if (ioctl(fd, TIOCGRS485, &rs) < 0)
        return -errno;
    rs.flags |= SER_RS485_ENABLED | SER_RS485_RTS_ON_SEND;
    rs.flags &= ~(uint32_t)SER_RS485_RTS_AFTER_SEND;
    if (rx_during_tx)
        rs.flags |= SER_RS485_RX_DURING_TX;
    else
        rs.flags &= ~(uint32_t)SER_RS485_RX_DURING_TX;
    rs.delay_rts_before_send = (uint32_t)before_ms;
    rs.delay_rts_after_send = (uint32_t)after_ms;
    if (ioctl(fd, TIOCSRS485, &rs) < 0)
        return -errno;
    return 0;
}

/* --- the modem lines --- */

int mbgw_rts_available(int fd)
{
    int bits;
    return ioctl(fd, TIOCMGET, &bits) < 0 ? -errno : 0;
}

int mbgw_tty_modem_lines(int fd, int dtr, int rts)
{
    int set = (dtr == 1 ? TIOCM_DTR : 0) | (rts == 1 ? TIOCM_RTS : 0);
    int clear = (dtr == 0 ? TIOCM_DTR : 0) | (rts == 0 ? TIOCM_RTS : 0);
    if (set && ioctl(fd, TIOCMBIS, &set) < 0)
        return -errno;
    if (clear && ioctl(fd, TIOCMBIC, &clear) < 0)
        return -errno;
    return 0;
}

int mbgw_tty_flow(int fd, int rtscts, int xonxoff)
{
    struct termios2 tio;
    if (ioctl(fd, TCGETS2, &tio) < 0)
        return -errno;
    tio.c_cflag &= ~(uint32_t)CRTSCTS;
    tio.c_iflag &= ~(uint32_t)(IXON | IXOFF | IXANY);
    if (rtscts)
        tio.c_cflag |= CRTSCTS;
    if (xonxoff) {
        tio.c_iflag |= IXON | IXOFF;
        tio.c_cc[VSTART] = 0x11; /* libmodbus zeroes c_cc: the characters are ^Q and ^S */
        tio.c_cc[VSTOP] = 0x13;
    }
    if (ioctl(fd, TCSETS2, &tio) < 0)
        return -errno;
    return 0;
}

int tty_set_rts(int fd, int on)
{
    int bit = TIOCM_RTS;
    return ioctl(fd, on ? TIOCMBIS : TIOCMBIC, &bit) < 0 ? -errno : 0;
}

/* --- the thread that owns the line --- */

int mbgw_line_thread_init(void)
{
    /* The line thread's timers fire on time, not up to 50 us late (the default slack). */
    return prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL) < 0 ? -errno : 0;
}

int mbgw_name_thread(const char *name)
{
    return prctl(PR_SET_NAME, (unsigned long)name, 0UL, 0UL, 0UL) < 0 ? -errno : 0;
}
