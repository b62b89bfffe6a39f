/* Line settings libmodbus cannot make: any baud rate (termios2 + BOTHER; libmodbus silently
 * turns rates outside its table into 9600), mark and space parity (CMSPAR; libmodbus refuses
 * them), low-latency mode, and the kernel's RS-485 direction control.
 * <asm/termbits.h> clashes with <termios.h>, hence this file of its own. */
#include <asm/ioctls.h>
#include <asm/termbits.h>
#include <errno.h>
#include <linux/serial.h>
#include <stddef.h>
#include <stdint.h>

#include "mbgw.h"

int ioctl(int fd, unsigned long request, ...);

uint32_t mbgw_tty_cflag(uint32_t cflag, int data_bits, char parity, int stop_bits)
{
    cflag &= ~(uint32_t)(CSIZE | PARENB | PARODD | CMSPAR | CSTOPB);
    cflag |= data_bits == 7 ? CS7 : CS8;
    switch (parity) {
    case 'e': cflag |= PARENB; break;
    case 'o': cflag |= PARENB | PARODD; break;
    case 'm': cflag |= PARENB | CMSPAR | PARODD; break;   /* parity bit always 1 */
    case 's': cflag |= PARENB | CMSPAR; break;            /* parity bit always 0 */
    default: break;
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
        tio.c_iflag &= ~(uint32_t)INPCK;       /* a device may answer in another parity */
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
